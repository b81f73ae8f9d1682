#!/usr/bin/env bash
# The API contract against a third-party client: schemathesis (every check, the examples,
# coverage, fuzzing and stateful phases) runs openapi.yaml against a real `calibd serve`
# on loopback with the operator token. Zero failures, or the check fails. Before that the
# document must pass a standard OpenAPI validator (openapi-spec-validator: it says 3.2.0
# and uses 3.2's `itemSchema` for the event streams).
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
VENV="${CALIBD_CI_VENV:-target/ci-venv}"
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
"$VENV/bin/pip" install -q --disable-pip-version-check schemathesis==4.32.5 openapi-spec-validator==0.9.0
"$VENV/bin/openapi-spec-validator" openapi.yaml
cargo build --quiet --bin calibd
. .ci/lib/daemon.sh
# No simulated lab: generated device jobs would queue campaigns on it for minutes.
CALIBD_LAB=none start_daemon
mkdir -p "$root/target/schemathesis"
"$VENV/bin/schemathesis" --config-file .ci/schemathesis/schemathesis.toml run openapi.yaml \
  --url "$url" -H "Authorization: Bearer $token" \
  --checks all --phases examples,coverage,fuzzing,stateful \
  --no-color \
  --report junit --report-dir "$root/target/schemathesis"
echo "api contract: schemathesis passed against $url"
