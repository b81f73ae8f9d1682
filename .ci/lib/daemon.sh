# Sourced by checks: start `calibd serve` on a free loopback port with a fresh data folder,
# wait (on its "listening" line, not a fixed time) until it serves, and stop it on exit.
# Sets: url, token (the generated operator token), data. Extra `calibd serve` arguments
# and environment are the caller's (e.g. `CALIBD_LAB=none start_daemon`).
start_daemon() {
  local target=${CARGO_TARGET_DIR:-$root/target}
  data=$(mktemp -d)
  local out="$data/stdout.log"
  "$target/debug/calibd" serve --listen 127.0.0.1:0 --data "$data" "$@" \
    >"$out" 2>"$data/stderr.log" &
  daemon_pid=$!
  trap 'kill "$daemon_pid" 2>/dev/null || true; wait "$daemon_pid" 2>/dev/null || true; rm -rf "$data"' EXIT
  url=""
  for _ in $(seq 1 600); do
    url=$(sed -n 's/^calibd listening on //p' "$out" | head -n1)
    [ -n "$url" ] && break
    kill -0 "$daemon_pid" 2>/dev/null || { cat "$data/stderr.log"; exit 1; }
    sleep 0.1
  done
  [ -n "$url" ] || { echo "calibd did not start"; cat "$data/stderr.log"; exit 1; }
  token=$(cat "$data/operator.token")
}
