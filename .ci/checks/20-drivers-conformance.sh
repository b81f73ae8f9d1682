#!/usr/bin/env bash
# Conformance of calibd's mock device servers with clients nobody on this team wrote
# (issue 6): qtm-rt 3.1.0 (QTM RT), abb-robot-client 0.4.0 (RWS + Digest), python-can 4.6.1
# (socketcand) + canopen 2.4.1 (SDO, CiA 402). The `qualisys` crate check runs in cargo test.
# Mocks listen on 127.0.0.1 port 0; the port is parsed from their ready line.
set -euo pipefail
cd "$(dirname "$0")/../.."

VENV="${CALIBD_CI_VENV:-target/ci-venv}"
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
"$VENV/bin/pip" install -q --disable-pip-version-check \
  qtm-rt==3.1.0 abb-robot-client==0.4.0 python-can==4.6.1 canopen==2.4.1

cargo build -q -p calibd-drivers --example mock
BIN="${CARGO_TARGET_DIR:-target}/debug/examples/mock"

tmp=$(mktemp -d)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  rm -rf "$tmp"
}
trap cleanup EXIT

for dev in qtm abb can; do
  "$BIN" "$dev" --listen 127.0.0.1:0 > "$tmp/$dev.out" 2>&1 &
  pids+=($!)
done

port_of() {
  for _ in $(seq 1 200); do
    if grep -q " ready " "$tmp/$1.out"; then
      awk '/ ready /{print $NF}' "$tmp/$1.out" | sed 's/.*://'
      return 0
    fi
    sleep 0.1
  done
  echo "mock $1 did not become ready:" >&2
  cat "$tmp/$1.out" >&2
  return 1
}

passed=0
failed=0
check() {
  local name=$1 script=$2 dev=$3 port
  port=$(port_of "$dev")
  echo "-- $name against mock $dev on 127.0.0.1:$port"
  if timeout 120 "$VENV/bin/python" "tests/conformance/$script" 127.0.0.1 "$port"; then
    passed=$((passed + 1))
  else
    echo "FAILED: $name" >&2
    failed=$((failed + 1))
  fi
}

check qtm-rt qtm_rt_check.py qtm
check abb-robot-client abb_rws_check.py abb
check python-can+canopen canopen_check.py can

# Fuzz the decoders briefly, opt-in (the sanitizer build alone takes ~15 min on 2 cores):
# CALIBD_CI_FUZZ_SECONDS=20 with cargo-fuzz and a nightly toolchain installed.
fuzz_s="${CALIBD_CI_FUZZ_SECONDS:-0}"
if [ "$fuzz_s" -gt 0 ] && cargo +nightly fuzz --version >/dev/null 2>&1; then
  for t in $(cd drivers/fuzz && cargo +nightly fuzz list); do
    echo "-- fuzz $t ($fuzz_s s)"
    if (cd drivers/fuzz && cargo +nightly fuzz run -O "$t" -- -max_total_time="$fuzz_s" -rss_limit_mb=2048) >"$tmp/fuzz-$t.log" 2>&1; then
      passed=$((passed + 1))
    else
      echo "FAILED: fuzz $t" >&2
      tail -30 "$tmp/fuzz-$t.log" >&2
      failed=$((failed + 1))
    fi
  done
else
  echo "-- fuzzing skipped (set CALIBD_CI_FUZZ_SECONDS and install cargo-fuzz; see drivers/TRANSCRIPTS.md)"
fi

echo "drivers conformance: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
