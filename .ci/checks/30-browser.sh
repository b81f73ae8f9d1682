#!/usr/bin/env bash
# Browser test of the daemon's web page in headless Debian Chromium, driven by
# playwright-core: submit the IRB 120 example from the form, watch it finish, download the
# calibrated model, open an uploaded HTML dataset (it must download, not run); open a
# finished PCR and humanoid job (submitted here with `calibd submit`), check their headline
# numbers and that every plot's "after" series is drawn at a visible size; follow a running
# TriCal campaign. Screenshots under target/browser/.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
if ! command -v chromium >/dev/null 2>&1; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
cargo build --quiet --bin calibd
target=${CARGO_TARGET_DIR:-$root/target}
(cd .ci/browser && npm ci --no-audit --no-fund --loglevel=error)
mkdir -p "$root/target/browser"
. .ci/lib/daemon.sh
start_daemon
# The humanoid example with a 3-fold cross-validation (its held-out plot), its file paths
# made absolute so the copy can live in the data folder.
python3 - "$root/examples/humanoid_identify_twin.json" "$data/humanoid_cv.json" <<'PY'
import json, os, sys
src, dst = sys.argv[1], sys.argv[2]
doc = json.load(open(src))
base = os.path.dirname(src)
for k, v in doc.items():
    if k != "kind" and isinstance(v, str) and os.path.isfile(os.path.join(base, v)):
        doc[k] = os.path.abspath(os.path.join(base, v))
doc.setdefault("options", {})["cross_validation"] = {"folds": 3}
json.dump(doc, open(dst, "w"))
PY
submit() { CALIBD_URL="$url" CALIBD_TOKEN="$token" "$target/debug/calibd" submit --priority=-1 "$1" | sed -n 's/^job \([0-9]*\) submitted$/\1/p'; }
pcr=$(submit examples/pcr_identify.json)
humanoid=$(submit "$data/humanoid_cv.json")
echo "submitted pcr.identify job $pcr and humanoid.identify job $humanoid"
JOBS="pcr:$pcr,humanoid:$humanoid" node .ci/browser/browser.mjs "$url" "$token" "$root/target/browser/calibd-page.png"
