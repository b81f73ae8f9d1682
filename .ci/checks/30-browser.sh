#!/usr/bin/env bash
# Browser test of the daemon's web page in headless Debian Chromium, driven by
# playwright-core: submit the IRB 120 example from the form, watch it finish, download the
# calibrated model, open an uploaded HTML dataset (it must download, not run), save a
# screenshot under target/browser/.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
if ! command -v chromium >/dev/null 2>&1; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
cargo build --quiet --bin calibd
(cd .ci/browser && npm ci --no-audit --no-fund --loglevel=error)
mkdir -p "$root/target/browser"
. .ci/lib/daemon.sh
start_daemon
node .ci/browser/browser.mjs "$url" "$token" "$root/target/browser/calibd-page.png"
