#!/usr/bin/env bash
# The API contract against a third-party client: schemathesis (every check, the examples,
# coverage, fuzzing and stateful phases) runs openapi.yaml against a real `calibd serve`
# on loopback with the operator token. Zero failures, or the check fails.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
VENV="${CALIBD_CI_VENV:-target/ci-venv}"
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
"$VENV/bin/pip" install -q --disable-pip-version-check schemathesis==4.32.5
target=${CARGO_TARGET_DIR:-$root/target}
cargo build --quiet --bin calibd
data=$(mktemp -d)
out="$data/stdout.log"
# No simulated lab: generated device jobs would queue campaigns on it for minutes.
CALIBD_LAB=none "$target/debug/calibd" serve --listen 127.0.0.1:0 --data "$data" \
  >"$out" 2>"$data/stderr.log" &
pid=$!
cleanup() { kill "$pid" 2>/dev/null || true; wait "$pid" 2>/dev/null || true; rm -rf "$data"; }
trap cleanup EXIT
url=""
for _ in $(seq 1 600); do
  url=$(sed -n 's/^calibd listening on //p' "$out" | head -n1)
  [ -n "$url" ] && break
  kill -0 "$pid" 2>/dev/null || { cat "$data/stderr.log"; exit 1; }
  sleep 0.1
done
[ -n "$url" ] || { echo "calibd did not start"; cat "$data/stderr.log"; exit 1; }
token=$(cat "$data/operator.token")
mkdir -p "$root/target/schemathesis"
"$VENV/bin/schemathesis" --config-file .ci/schemathesis/schemathesis.toml run openapi.yaml \
  --url "$url" -H "Authorization: Bearer $token" \
  --checks all --phases examples,coverage,fuzzing,stateful \
  --no-color \
  --report junit --report-dir "$root/target/schemathesis"
echo "api contract: schemathesis passed against $url"
