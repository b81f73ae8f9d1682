#!/usr/bin/env bash
# Browser test of the daemon's web page in headless Debian Chromium, driven by
# playwright-core: submit the IRB 120 example from the form, watch it finish, download the
# calibrated model, open an uploaded HTML dataset (it must download, not run); open a
# finished PCR and humanoid job (submitted here with `calibd submit`), check their headline
# numbers and that every plot's "after" series is drawn at a visible size, and the PCR
# Table 2 bars; open a finished serial.design (its DETMAX O1 history) and serial.dispersion
# (its box plots on a log axis); follow a running TriCal campaign. Screenshots under
# target/browser/.
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
# Copies of examples with their file paths made absolute (so the copy can live in the data
# folder) and some fields changed: the humanoid example with a 3-fold cross-validation (its
# held-out plot), a small dispersion study (its box plots).
copy_example() {
  python3 - "$root/examples/$1" "$data/$2" "$3" <<'PY'
import json, os, sys
src, dst, edit = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
doc = json.load(open(src))
base = os.path.dirname(src)
for k, v in doc.items():
    if k != "kind" and isinstance(v, str) and os.path.isfile(os.path.join(base, v)):
        doc[k] = os.path.abspath(os.path.join(base, v))
for k, v in edit.items():
    if isinstance(v, dict):
        doc.setdefault(k, {}).update(v)
    else:
        doc[k] = v
json.dump(doc, open(dst, "w"))
PY
}
copy_example humanoid_identify_twin.json humanoid_cv.json '{"options": {"cross_validation": {"folds": 3}}}'
copy_example serial_dispersion.json dispersion_small.json '{"sizes": [30, 60], "repetitions": 4}'
submit() { CALIBD_URL="$url" CALIBD_TOKEN="$token" "$target/debug/calibd" submit --priority=-1 "$1" | sed -n 's/^job \([0-9]*\) submitted$/\1/p'; }
pcr=$(submit examples/pcr_identify.json)
humanoid=$(submit "$data/humanoid_cv.json")
design=$(submit examples/serial_design.json)
dispersion=$(submit "$data/dispersion_small.json")
echo "submitted pcr.identify job $pcr, humanoid.identify job $humanoid, serial.design job $design, serial.dispersion job $dispersion"
JOBS="pcr:$pcr,humanoid:$humanoid,design:$design,dispersion:$dispersion" node .ci/browser/browser.mjs "$url" "$token" "$root/target/browser/calibd-page.png"
