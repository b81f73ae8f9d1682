#!/usr/bin/env bash
# Browser test of the daemon's web page in headless Debian Chromium, driven by
# playwright-core: submit the IRB 120 example from the form, watch it finish, download the
# calibrated model, save a screenshot under target/browser/.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
if ! command -v chromium >/dev/null 2>&1; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
target=${CARGO_TARGET_DIR:-$root/target}
cargo build --quiet --bin calibd
(cd .ci/browser && npm ci --no-audit --no-fund --loglevel=error)
mkdir -p "$root/target/browser"
data=$(mktemp -d)
out="$data/stdout.log"
"$target/debug/calibd" serve --listen 127.0.0.1:0 --data "$data" >"$out" 2>"$data/stderr.log" &
pid=$!
cleanup() { kill "$pid" 2>/dev/null || true; wait "$pid" 2>/dev/null || true; rm -rf "$data"; }
trap cleanup EXIT
url=""
for _ in $(seq 1 300); do
  url=$(sed -n 's/^calibd listening on //p' "$out" | head -n1)
  [ -n "$url" ] && break
  kill -0 "$pid" 2>/dev/null || { cat "$data/stderr.log"; exit 1; }
  sleep 0.1
done
[ -n "$url" ] || { echo "calibd did not start"; cat "$data/stderr.log"; exit 1; }
token=$(cat "$data/operator.token")
node .ci/browser/browser.mjs "$url" "$token" "$root/target/browser/calibd-page.png"
