#!/usr/bin/env bash
# PostgreSQL store (issue 16): install PostgreSQL from Debian's packages if it is missing,
# then run the store tests on PostgreSQL (the same tests as on SQLite, plus the shared
# queue) and the three-daemon fleet test, each on a throw-away cluster (initdb + postgres
# on a temp dir, loopback port, as `nobody`). CALIBD_REQUIRE_PG=1 turns "skipped:
# PostgreSQL not installed" into a failure, so CI really runs them.
set -euo pipefail
cd "$(dirname "$0")/../.."

if ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -q
  apt-get install -y -q --no-install-recommends postgresql
fi
bin=$(ls -d /usr/lib/postgresql/*/bin | sort -V | tail -1)
echo "-- PostgreSQL binaries: $bin ($("$bin/postgres" --version))"
export CALIBD_PG_BIN="$bin" CALIBD_REQUIRE_PG=1

cargo test -p calibd --lib store:: -- --nocapture 2>&1 | tee /tmp/calibd-pg-store.log | grep -E "claim latency|test result|FAILED|panicked" || true
grep -q "test result: ok" /tmp/calibd-pg-store.log
cargo test -p calibd --test it fleet:: -- --nocapture 2>&1 | tee /tmp/calibd-pg-fleet.log | grep -E "fleet throughput|jobs per daemon|killed|cancel on the other|campaign |test result|FAILED|panicked" || true
grep -q "test result: ok" /tmp/calibd-pg-fleet.log
