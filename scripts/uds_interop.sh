#!/usr/bin/env bash
# Interoperability check of the replay daemon's UDS service (scripts/uds_interop.py): makes
# the Python venv (scripts/requirements-uds.txt, pinned), builds the daemon in release,
# starts it on config/replay-uds.toml with a throwaway secret, a fresh store (generation 1
# seeded from the fixture's truth) and a free port, waits for the socketcand endpoint, runs
# the checks, and always stops the daemon. Exit status: that of the checks.
#
#   scripts/uds_interop.sh            # venv in target/uds-venv (UDS_VENV overrides)
#   FLOOD=10000 ROOMCAL_BIN=target/release/roomcal scripts/uds_interop.sh
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
venv=${UDS_VENV:-$repo/target/uds-venv}
req=scripts/requirements-uds.txt

echo "== uds interop: python venv ($venv)"
if [ ! -x "$venv/bin/python" ] || ! cmp -s "$req" "$venv/requirements-uds.txt"; then
    rm -rf "$venv"
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q --disable-pip-version-check -r "$req"
    cp "$req" "$venv/requirements-uds.txt"
fi

# ROOMCAL_BIN: an already built roomcal binary instead of the release build.
bin=${ROOMCAL_BIN:-}
if [ -z "$bin" ]; then
    echo "== uds interop: release build"
    cargo build --release --bin roomcal
    bin=target/release/roomcal
fi

tmp=$(mktemp -d "${TMPDIR:-/tmp}/roomcal-uds.XXXXXX")
daemon_pid=
cleanup() {
    if [ -n "$daemon_pid" ] && kill -0 "$daemon_pid" 2>/dev/null; then
        kill -INT "$daemon_pid" 2>/dev/null || true   # the daemon stops on SIGINT
        for _ in $(seq 50); do kill -0 "$daemon_pid" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$daemon_pid" 2>/dev/null || true
        wait "$daemon_pid" 2>/dev/null || true
    fi
    rm -rf "$tmp"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# A throwaway per-vehicle secret, a fresh store and a free port.
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$tmp/secret"
chmod 600 "$tmp/secret"  # the daemon refuses a secret others can read
"$venv/bin/python" scripts/uds_interop.py --seed-store "$tmp/store"
port=$("$venv/bin/python" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
sed -e "s#\.\./#$repo/#g" \
    -e "s#^store = .*#store = \"$tmp/store\"#" \
    -e "s#^secret_file = .*#secret_file = \"$tmp/secret\"#" \
    -e "s#socketcand:127\.0\.0\.1:29536#socketcand:127.0.0.1:$port#" \
    config/replay-uds.toml > "$tmp/roomcal.toml"

echo "== uds interop: daemon on socketcand:127.0.0.1:$port (log: $tmp/daemon.log)"
NO_COLOR=1 RUST_LOG=${RUST_LOG:-info} "$bin" daemon --config "$tmp/roomcal.toml" \
    > "$tmp/daemon.log" 2>&1 &
daemon_pid=$!
# Wait for the daemon's own word that it listens (not just any process on the port).
for i in $(seq 301); do
    if grep -q "listening on 127.0.0.1:$port" "$tmp/daemon.log"; then break; fi
    if ! kill -0 "$daemon_pid" 2>/dev/null || [ "$i" = 301 ]; then
        echo "FAIL the daemon is not listening on 127.0.0.1:$port:"; cat "$tmp/daemon.log"; exit 1
    fi
    sleep 0.1
done

echo "== uds interop: checks"
status=0
timeout 300 "$venv/bin/python" scripts/uds_interop.py --port "$port" --store "$tmp/store" \
    --secret-file "$tmp/secret" --flood "${FLOOD:-10000}" || status=$?
if ! kill -0 "$daemon_pid" 2>/dev/null; then
    echo "FAIL the daemon died during the checks"; status=1
fi
if [ "$status" != 0 ]; then
    echo "== daemon log (last 40 lines)"; tail -n 40 "$tmp/daemon.log"
fi
exit "$status"
