#!/usr/bin/env bash
# Deploy check: follows deploy/OPERATIONS.md ("Installing with systemd") in a scratch root.
# Runs deploy/install.sh (the script OPERATIONS.md tells the admin to run) with DESTDIR set,
# starts the installed daemon the way the installed unit does (its ExecStart= and
# Environment=, paths moved into the scratch root) as an unprivileged user (nobody) with a
# state directory like StateDirectory= makes, waits for `calibd health`, checks that the
# operator token was generated and that it (and only it) opens the API, and verifies the
# installed unit with systemd-analyze.
set -euo pipefail
cd "$(dirname "$0")/../.."
repo=$(pwd)
target=${CARGO_TARGET_DIR:-$repo/target}
uid=65534 # nobody
gid=65534

fail() {
  echo "40-deploy: FAIL: $*" >&2
  exit 1
}

for tool in curl setpriv; do
  command -v "$tool" >/dev/null 2>&1 || {
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq curl util-linux >/dev/null
  }
done
if ! command -v systemd-analyze >/dev/null 2>&1; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq systemd >/dev/null
fi

cargo build --quiet --bin calibd

# The scratch root stands in for /; nobody must be able to walk into it like into /.
scratch=$(mktemp -d /tmp/deploy-check.XXXXXX)
chmod 0755 "$scratch"
root=$scratch/root
mkdir -m 0755 "$root"
pid=""
cleanup() {
  if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
    kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 1 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
  fi
  [ -z "$pid" ] || wait "$pid" 2>/dev/null || true
  rm -rf "$scratch"
}
trap cleanup EXIT

# 1. Install exactly as OPERATIONS.md says.
grep -q '^    sudo deploy/install.sh$' deploy/OPERATIONS.md ||
  fail "deploy/OPERATIONS.md no longer installs with deploy/install.sh: update this check"
DESTDIR=$root CALIBD_BIN=$target/debug/calibd deploy/install.sh
unit=$root/etc/systemd/system/calibd.service
for f in usr/local/bin/calibd etc/calibd/calibd.toml etc/systemd/system/calibd.service \
  etc/calibd/lab.example.toml etc/calibd/models/irb120.json etc/calibd/models/pcr3pf.json \
  etc/calibd/models/talos_reduced.urdf; do
  stat -c '40-deploy: installed %n mode %a owner %U:%G' "$root/$f"
done

# 2. The unit's command and environment, with absolute paths moved into the scratch root.
exec_start=$(sed -n 's/^ExecStart=//p' "$unit")
[ -n "$exec_start" ] || fail "no ExecStart= in the unit"
read -r -a argv <<<"$exec_start"
for i in "${!argv[@]}"; do
  case ${argv[$i]} in /*) argv[$i]=$root${argv[$i]} ;; esac
done
envs=()
while IFS= read -r kv; do
  case ${kv#*=} in /*) kv=${kv%%=*}=$root${kv#*=} ;; esac
  envs+=("$kv")
done < <(sed -n 's/^Environment=//p' "$unit")
state_dir=$(sed -n 's/^StateDirectory=//p' "$unit")
state_mode=$(sed -n 's/^StateDirectoryMode=//p' "$unit")
umask_unit=$(sed -n 's/^UMask=//p' "$unit")
[ "$state_dir" = calibd ] || fail "StateDirectory=$state_dir: this check expects calibd"
# StateDirectory=: /var/lib/calibd owned by the service user with StateDirectoryMode=. (With
# DynamicUser= it lives in /var/lib/private/calibd, reached through the /var/lib/calibd
# symlink; the private 0700 parent is only entered through the service's own namespace.)
data=$root/var/lib/$state_dir
install -d -m 0755 "$root/var" "$root/var/lib"
install -d -m "${state_mode:-0755}" -o "$uid" -g "$gid" "$data"
case " ${envs[*]} " in *" CALIBD_DATA=$data "*) ;; *) fail "the unit does not point CALIBD_DATA at its state directory" ;; esac

# nobody can walk to the installed files (a failure below is then about their modes).
as_nobody=(setpriv --reuid="$uid" --regid="$gid" --clear-groups)
"${as_nobody[@]}" test -x "$root/etc/calibd" || fail "nobody cannot enter $root/etc/calibd"

# 3. The installed settings name the installed lab file (absolute: moved into the scratch
# root with CALIBD_LAB, as the unit's paths are). Without it the daemon refuses to start
# and says where the example is.
lab_file=$(sed -n 's/^lab = "\(.*\)"$/\1/p' "$root/etc/calibd/calibd.toml")
[ "$lab_file" = /etc/calibd/lab.toml ] || fail "calibd.toml names lab = \"$lab_file\", expected the installed lab file"
[ -s "$root$lab_file" ] || fail "install.sh did not install $lab_file"
if missing=$(env -i PATH=/usr/local/bin:/usr/bin:/bin "${envs[@]}" CALIBD_LISTEN=127.0.0.1:0 \
  CALIBD_LAB="$root/etc/calibd/absent.toml" "${as_nobody[@]}" "${argv[@]}" 2>&1 </dev/null); then
  fail "calibd started without its lab file"
fi
case $missing in *"absent.toml does not exist"*"lab.example.toml"*) ;; *) fail "no clear refusal without the lab file: $missing" ;; esac
echo "40-deploy: without its lab file calibd refuses to start: $(echo "$missing" | tail -n1 | cut -c1-160)"
# The admin's step of OPERATIONS.md: the RWS password the lab file names, readable by the
# service (its path moved into the scratch root).
install -d -m 0755 "$root/etc/calibd/secrets"
printf 'rws-secret\n' >"$root/etc/calibd/secrets/rws-password"
chmod 0644 "$root/etc/calibd/secrets/rws-password"
sed -i "s#\"/etc/calibd/secrets/#\"$root/etc/calibd/secrets/#" "$root$lab_file"

# 4. Start it as nobody, on a free loopback port (CALIBD_LISTEN overrides the file's listen).
out=$scratch/stdout.log
err=$scratch/stderr.log
# Created before the start: the wait below reads them at once, and under load the subshell's
# redirection could come later (a `sed: can't read` that ended the check under set -e).
: >"$out"
: >"$err"
(
  umask "${umask_unit:-0022}"
  exec env -i PATH=/usr/local/bin:/usr/bin:/bin "${envs[@]}" CALIBD_LISTEN=127.0.0.1:0 \
    CALIBD_LAB="$root$lab_file" "${as_nobody[@]}" "${argv[@]}" >"$out" 2>"$err"
) &
pid=$!
echo "40-deploy: started as uid $uid: ${argv[*]}"

show_logs() {
  echo "--- calibd stdout" >&2
  cat "$out" >&2 || true
  echo "--- calibd stderr" >&2
  tail -n 40 "$err" >&2 || true
}
url=""
deadline=$((SECONDS + 90))
while [ -z "$url" ]; do
  url=$(sed -n 's/^calibd listening on //p' "$out" | head -n1)
  [ -n "$url" ] && break
  kill -0 "$pid" 2>/dev/null || { show_logs; fail "calibd exited before listening"; }
  [ "$SECONDS" -lt "$deadline" ] || { show_logs; fail "calibd did not listen within 90 s"; }
  sleep 0.1
done
case $url in http://127.0.0.1:*) ;; *) fail "unexpected listening line: $url" ;; esac
echo "40-deploy: listening on $url"

# 5. `calibd health` (the container's HEALTHCHECK) until it answers 200.
calibd=$root/usr/local/bin/calibd
deadline=$((SECONDS + 60))
until health=$("$calibd" health --server "$url" --timeout 5); do
  kill -0 "$pid" 2>/dev/null || { show_logs; fail "calibd exited: $health"; }
  [ "$SECONDS" -lt "$deadline" ] || { show_logs; fail "not healthy within 60 s: $health"; }
  sleep 0.2
done
echo "40-deploy: $health"
# The installed lab file's cells, not a simulated lab (its devices are at the example's
# addresses: absent here, so the cells are listed but unavailable).
grep -q 'simulated lab started' "$err" && { show_logs; fail "the installed daemon started a simulated lab"; }

# 6. The generated operator token opens the API; nothing else does.
tok=$data/operator.token
[ -s "$tok" ] || { show_logs; fail "no operator token in $tok (tokens preset in the example config?)"; }
[ "$(stat -c '%a %u' "$tok")" = "600 $uid" ] || fail "operator.token: $(stat -c 'mode %a owner %u' "$tok")"
token=$(tr -d '[:space:]' <"$tok")
code() { curl --noproxy '*' -s -o /dev/null -w '%{http_code}' --max-time 20 "$@"; }
c=$(code -H "Authorization: Bearer $token" "$url/v1/jobs")
[ "$c" = 200 ] || { show_logs; fail "GET /v1/jobs with the operator token: HTTP $c"; }
echo "40-deploy: GET /v1/jobs with the operator token: 200"
c=$(code "$url/v1/jobs")
[ "$c" = 401 ] || fail "GET /v1/jobs without a token: HTTP $c (want 401)"
c=$(code -H "Authorization: Bearer not-$token" "$url/v1/jobs")
[ "$c" = 401 ] || fail "GET /v1/jobs with a wrong token: HTTP $c (want 401)"
echo "40-deploy: GET /v1/jobs without a token / with a wrong one: 401"
lab_json=$(curl --noproxy '*' -s --max-time 20 -H "Authorization: Bearer $token" "$url/v1/lab")
for cell in irb120 pcr3pf talos; do
  case $lab_json in *"\"$cell\""*) ;; *) show_logs; fail "GET /v1/lab does not list the installed lab's cell $cell: $lab_json" ;; esac
done
echo "40-deploy: GET /v1/lab lists the installed lab file's cells irb120, pcr3pf, talos"

# 7. SIGTERM (systemctl stop) ends it cleanly within the unit's TimeoutStopSec=.
stop_s=$(sed -n 's/^TimeoutStopSec=//p' "$unit")
kill -TERM "$pid"
deadline=$((SECONDS + ${stop_s:-30}))
while kill -0 "$pid" 2>/dev/null; do
  [ "$SECONDS" -lt "$deadline" ] || fail "calibd did not stop within ${stop_s:-30} s of SIGTERM"
  sleep 0.1
done
rc=0
wait "$pid" || rc=$?
pid=""
[ "$rc" = 0 ] || { show_logs; fail "calibd exited with status $rc after SIGTERM"; }
if health=$("$calibd" health --server "$url" --timeout 2); then
  fail "calibd health succeeds with the daemon stopped: $health"
fi
echo "40-deploy: stopped on SIGTERM; health now fails: $health"

# 8. The installed unit passes systemd-analyze verify (offline; --root: its ExecStart= binary
# is the scratch root's, the units it depends on are copies of the system's).
verify_log=$scratch/verify.log
for d in /usr/lib/systemd/system /lib/systemd/system; do
  [ -d "$d" ] || continue
  mkdir -p "$root/usr/lib/systemd"
  cp -a "$d" "$root/usr/lib/systemd/system"
  break
done
vrc=0
SYSTEMD_LOG_COLOR=0 systemd-analyze verify --root="$root" "$unit" >"$verify_log" 2>&1 || vrc=$?
# Lines about other units (the host's or the missing targets') are not ours.
if [ "$vrc" != 0 ] || grep -q 'calibd' "$verify_log"; then
  cat "$verify_log" >&2
  fail "systemd-analyze verify reports problems with the unit (status $vrc)"
fi
echo "40-deploy: systemd-analyze verify: ok"

# 9. The container build context leaves out target/ and .git (podman and docker files agree).
cmp -s .containerignore .dockerignore || fail ".containerignore and .dockerignore differ"
grep -qx '\*\*/target' .containerignore && grep -qx '\.git' .containerignore ||
  fail ".containerignore does not exclude target/ and .git"
grep -q '^HEALTHCHECK .*"/usr/local/bin/calibd", "health"' deploy/Containerfile ||
  fail "deploy/Containerfile's HEALTHCHECK does not run calibd health"
# 10. The Containerfile's dependency layer: its COPY'd manifests with the stub crate roots it
# makes must form a workspace cargo accepts (a new [[bin]]/[[bench]] without a stub would
# break the image build). Its RUN line is run as written, with the release build replaced
# by `cargo metadata` (no container registry is reachable here to build the image itself).
layer=$(mktemp -d)
cp Cargo.toml Cargo.lock "$layer/"
mkdir -p "$layer/drivers" && cp drivers/Cargo.toml "$layer/drivers/"
grep -qx 'COPY fft fft' deploy/Containerfile || fail "deploy/Containerfile's dependency layer does not copy fft/"
cp -r fft "$layer/"
stub=$(awk '/^RUN mkdir -p src drivers\/src/,/^COPY \. \./' deploy/Containerfile |
  grep -v '^COPY' | sed -e 's/^RUN //' -e 's/\\$//' | tr '\n' ' ')
[ -n "$stub" ] || fail "deploy/Containerfile has no dependency layer (RUN mkdir -p src drivers/src ...)"
stub=${stub//cargo build --release --locked --bin calibd/cargo metadata --locked --format-version 1 >\/dev\/null}
(cd "$layer" && bash -c "$stub") || fail "the Containerfile's dependency layer does not resolve: $stub"
rm -rf "$layer"
echo "40-deploy: the Containerfile's dependency layer resolves with its stubs"
for flag in --read-only --cap-drop=ALL 'no-new-privileges' '--format docker'; do
  grep -q -- "$flag" deploy/OPERATIONS.md || fail "OPERATIONS.md's container section lacks $flag"
done
echo "40-deploy: passed"
