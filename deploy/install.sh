#!/bin/sh
# Installs calibd for systemd, as deploy/OPERATIONS.md describes (run it as root from the
# repository after `cargo build --release --locked --bin calibd`):
#   sudo deploy/install.sh
# DESTDIR: root to install under (default: the real /); CALIBD_BIN: the binary to install
# (default: target/release/calibd). .ci/checks/40-deploy.sh runs this very script into a
# scratch root and starts the installed daemon as an unprivileged user.
set -eu
DESTDIR=${DESTDIR:-}
bin=${CALIBD_BIN:-}
# Paths given relative to where this is run from, the rest relative to the repository.
case $DESTDIR in ''|/*) ;; *) DESTDIR=$(pwd)/$DESTDIR ;; esac
case $bin in ''|/*) ;; *) bin=$(pwd)/$bin ;; esac
cd "$(dirname "$0")/.."
bin=${bin:-target/release/calibd}
[ -x "$bin" ] || { echo "install.sh: no binary at $bin (cargo build --release --locked --bin calibd)" >&2; exit 1; }

# The binary.
install -D -m 0755 "$bin" "$DESTDIR/usr/local/bin/calibd"
# The settings: world-readable, since the unit's dynamic user must read them (they hold no
# secrets: tokens are stored as SHA-256 hashes). An existing file is kept, made readable.
install -d -m 0755 "$DESTDIR/etc/calibd"
if [ -e "$DESTDIR/etc/calibd/calibd.toml" ]; then
  echo "install.sh: keeping the existing $DESTDIR/etc/calibd/calibd.toml (the new example is deploy/calibd.toml)"
  case $(stat -c %A "$DESTDIR/etc/calibd/calibd.toml") in
    ???????r??) ;;
    *) chmod 0644 "$DESTDIR/etc/calibd/calibd.toml"
       echo "install.sh: made it mode 0644: the service's dynamic user could not read it" ;;
  esac
else
  install -m 0644 deploy/calibd.toml "$DESTDIR/etc/calibd/calibd.toml"
fi
# The example lab and the nominal models it names (relative paths: models/ beside it).
# Models already installed are kept.
install -m 0644 deploy/lab.example.toml "$DESTDIR/etc/calibd/lab.example.toml"
# calibd.toml names /etc/calibd/lab.toml: a first install gets the example there, to be
# edited (its devices' addresses, secrets); an existing lab file is kept.
if [ -e "$DESTDIR/etc/calibd/lab.toml" ]; then
  echo "install.sh: keeping the existing $DESTDIR/etc/calibd/lab.toml"
else
  install -m 0644 deploy/lab.example.toml "$DESTDIR/etc/calibd/lab.toml"
  echo "install.sh: installed the example lab as $DESTDIR/etc/calibd/lab.toml: describe your cells in it"
fi
install -d -m 0755 "$DESTDIR/etc/calibd/models"
for m in deploy/models/*; do
  dest="$DESTDIR/etc/calibd/models/$(basename "$m")"
  [ -e "$dest" ] || install -m 0644 "$m" "$dest"
done
# The unit and the manual it names.
install -D -m 0644 deploy/calibd.service "$DESTDIR/etc/systemd/system/calibd.service"
install -D -m 0644 deploy/OPERATIONS.md "$DESTDIR/usr/share/doc/calibd/OPERATIONS.md"
echo "install.sh: installed calibd under ${DESTDIR:-/}"
