#!/usr/bin/env bash
# Installs a roomcal .deb into a throwaway Debian root (chroot) and walks it through its life:
# install, reinstall, an operator's edits and a daemon run as the service user, two upgrades (the second changes a packaged
# config), remove, remove again, reinstall, purge, purge again, install after purge. Checks
# the system user, the store directory, that a changed config survives every upgrade and
# remove, and what purge leaves. One line per check; exit 1 on any failure. Needs root.
#
#   scripts/deb_install_test.sh target/debian/roomcal_0.1.0-1_amd64.deb [ROOT]
#
# ROOT is a Debian root to use (e.g. `debootstrap --variant=minbase bookworm ROOT`); any
# roomcal in it is purged and its user deleted first. Without ROOT one is made with
# debootstrap in a temporary directory and deleted afterwards (a few minutes, needs the
# Debian archive). systemd does not run in the chroot: the scripts' systemctl calls are
# skipped there, as on an image build, so starting the unit is not exercised here.
set -euo pipefail

deb=$(realpath "${1:?usage: scripts/deb_install_test.sh PACKAGE.deb [ROOT]}")
repo=$(realpath "$(dirname "$0")/..")
root=${2:-}
work=$(mktemp -d)
cleanup() {
    rm -rf "$work"
    [ -z "${made_root:-}" ] || rm -rf "$made_root"
}
trap cleanup EXIT
if [ -z "$root" ]; then
    made_root=$work-root
    root=$made_root
    echo "making a throwaway root in $root (debootstrap --variant=minbase bookworm)"
    debootstrap --variant=minbase bookworm "$root" >"$work/debootstrap.log" 2>&1 \
        || { tail -n 20 "$work/debootstrap.log"; exit 1; }
fi
root=$(realpath "$root")
failures=0

pass() { echo "ok    $*"; }
fail() { echo "FAIL  $*"; failures=$((failures + 1)); }
check() {
    local what=$1
    shift
    if "$@"; then pass "$what"; else fail "$what"; fi
}
in_root() { chroot "$root" "$@"; }
dpkg_in_root() { # dpkg in the root, its output kept for the failure message
    if ! in_root dpkg "$@" </dev/null >"$work/dpkg.log" 2>&1; then
        echo "dpkg $* failed:"
        cat "$work/dpkg.log"
        return 1
    fi
}
# shellcheck disable=SC2016 # ${Status} is dpkg-query's format, not the shell's
status() { in_root dpkg-query -W -f '${Status}' roomcal 2>/dev/null || true; }
uid() { in_root getent passwd roomcal | cut -d: -f3; }

# Upgrade packages made from the one under test: the same files at a higher version, and one
# whose packaged roomcal.toml also changed (as a release that edits the default would).
repack() { # repack SUFFIX CHANGE_CONFIG OUT
    local tree=$work/tree-$1
    dpkg-deb -R "$deb" "$tree"
    sed -i "s/^Version: .*/&+$1/" "$tree/DEBIAN/control"
    if [ "$2" = yes ]; then
        echo "# a default changed by a later release" >>"$tree/etc/roomcal/roomcal.toml"
    fi
    (cd "$tree" && find . -type f ! -path './DEBIAN/*' -printf '%P\0' | sort -z \
        | xargs -0 md5sum >DEBIAN/md5sums)
    dpkg-deb --root-owner-group -b "$tree" "$3" >/dev/null
}
repack up1 no "$root/tmp/roomcal-up1.deb"
repack up2 yes "$root/tmp/roomcal-up2.deb"
cp "$deb" "$root/tmp/roomcal.deb"

echo "== a clean root"
in_root dpkg --purge roomcal >/dev/null 2>&1 || true
in_root userdel roomcal >/dev/null 2>&1 || true
in_root groupdel roomcal >/dev/null 2>&1 || true
check "no roomcal user before install" bash -c "! chroot '$root' getent passwd roomcal >/dev/null"

echo "== install"
check "dpkg -i installs" dpkg_in_root -i /tmp/roomcal.deb
check "status: install ok installed" test "$(status)" = "install ok installed"
check "the binary runs in the root" bash -c "chroot '$root' /usr/bin/roomcal --version >/dev/null"
passwd_line=$(in_root getent passwd roomcal || true)
IFS=: read -r _ _ uid0 gid0 _ home shell <<<"$passwd_line"
check "user roomcal is a system user (uid $uid0 < 1000)" test "${uid0:-1000}" -lt 1000
check "its group is roomcal" test "$(in_root getent group roomcal | cut -d: -f3)" = "$gid0"
check "its home is the store, its shell nologin ($home, $shell)" \
    test "$home:$shell" = "/var/lib/roomcal:/usr/sbin/nologin"
check "no home was created elsewhere" test ! -e "$root/home/roomcal"
check "store /var/lib/roomcal is 750 roomcal:roomcal" \
    test "$(in_root stat -c '%a %U:%G' /var/lib/roomcal)" = "750 roomcal:roomcal"
check "configs installed" test -f "$root/etc/roomcal/roomcal.toml" -a -f "$root/etc/roomcal/room.toml"
check "unit installed" test -f "$root/lib/systemd/system/roomcal.service"
check "no secret shipped" test ! -e "$root/etc/roomcal/secret"

echo "== reinstall (configure runs again)"
check "dpkg -i again succeeds" dpkg_in_root -i /tmp/roomcal.deb
check "same uid after reinstall" test "$(uid)" = "$uid0"

echo "== the operator provisions and edits; the daemon writes the store"
echo "# site: this vehicle's edit" >>"$root/etc/roomcal/roomcal.toml"
edited=$(md5sum <"$root/etc/roomcal/roomcal.toml")
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' >"$root/etc/roomcal/secret"
in_root chown roomcal:roomcal /etc/roomcal/secret
chmod 0600 "$root/etc/roomcal/secret"
secret=$(md5sum <"$root/etc/roomcal/secret")
# The packaged daemon, as the service user, on the repository's fixture replayed (no camera,
# LiDAR or CAN in a chroot): one run must land in the store the package made.
fixture=$repo/fixtures/six-boards-pandar64
mkdir -p "$root/tmp/roomcal-replay"
cp "$fixture/room.toml" "$fixture/image.png" "$fixture/cloud.pcap" "$fixture/angles.csv" \
    "$root/tmp/roomcal-replay/"
cat >"$root/tmp/roomcal-replay/roomcal.toml" <<'TOML'
room = "room.toml"
store = "/var/lib/roomcal"
[camera]
source = "replay:image.png"
[lidar]
source = "replay:cloud.pcap"
calibration = "angles.csv"
[trigger]
mode = "auto"
settle_s = 2.0
sweeps = 1
TOML
check "the daemon as user roomcal calibrates into the store (replayed fixture)" \
    bash -c "timeout 300 chroot --userspec=roomcal:roomcal '$root' /usr/bin/roomcal daemon \
        --config /tmp/roomcal-replay/roomcal.toml --once >'$work/daemon.log' 2>&1 \
        || { tail -n 5 '$work/daemon.log'; exit 1; }"
check "current.json is the service user's" \
    test "$(in_root stat -c '%U' /var/lib/roomcal/current.json 2>/dev/null)" = roomcal
kept() { # kept WHEN: the edit, the secret and the store are as the operator left them
    check "$1: the edited roomcal.toml is kept" test "$(md5sum <"$root/etc/roomcal/roomcal.toml")" = "$edited"
    check "$1: the secret is kept" test "$(md5sum <"$root/etc/roomcal/secret" 2>/dev/null)" = "$secret"
    check "$1: the store is kept" grep -q generation "$root/var/lib/roomcal/current.json"
    check "$1: same uid" test "$(uid)" = "$uid0"
}

echo "== upgrade, the packaged configs unchanged"
check "dpkg -i the upgrade" dpkg_in_root -i /tmp/roomcal-up1.deb
check "version is the upgrade's" bash -c "chroot '$root' dpkg-query -W -f '\${Version}' roomcal | grep -q '+up1$'"
kept "upgrade"
check "upgrade: no .dpkg-dist (nothing to offer)" test ! -e "$root/etc/roomcal/roomcal.toml.dpkg-dist"

echo "== upgrade whose packaged roomcal.toml changed (--force-confdef --force-confold, as unattended upgrades run)"
check "dpkg -i the second upgrade" dpkg_in_root --force-confdef --force-confold -i /tmp/roomcal-up2.deb
kept "changed default"
check "changed default: the new default is beside it as .dpkg-dist" \
    grep -q "a default changed by a later release" "$root/etc/roomcal/roomcal.toml.dpkg-dist"
rm -f "$root/etc/roomcal/roomcal.toml.dpkg-dist"

echo "== remove"
check "dpkg -r removes" dpkg_in_root -r roomcal
check "status: deinstall ok config-files" test "$(status)" = "deinstall ok config-files"
check "binary and unit are gone" test ! -e "$root/usr/bin/roomcal" -a ! -e "$root/lib/systemd/system/roomcal.service"
kept "remove"
check "dpkg -r again succeeds" dpkg_in_root -r roomcal

echo "== install after remove"
check "dpkg -i after remove" dpkg_in_root -i /tmp/roomcal-up2.deb
kept "reinstall after remove"

echo "== purge"
check "dpkg -P purges" dpkg_in_root -P roomcal
check "status: not installed" test -z "$(status)" -o "$(status)" = "unknown ok not-installed"
check "/etc/roomcal is gone (configs and secret)" test ! -e "$root/etc/roomcal"
check "the store is gone" test ! -e "$root/var/lib/roomcal"
check "the user is kept (Debian policy), same uid" test "$(uid)" = "$uid0"
check "dpkg -P again succeeds" dpkg_in_root -P roomcal

echo "== install after purge"
check "dpkg -i after purge" dpkg_in_root -i /tmp/roomcal.deb
check "the user is reused (same uid)" test "$(uid)" = "$uid0"
check "fresh configs are the packaged ones" \
    bash -c "dpkg-deb --fsys-tarfile '$deb' | tar -xO ./etc/roomcal/roomcal.toml | cmp -s - '$root/etc/roomcal/roomcal.toml'"
check "the store is made again" test "$(in_root stat -c '%a %U' /var/lib/roomcal)" = "750 roomcal"
in_root dpkg --purge roomcal >/dev/null 2>&1 || true

if [ "$failures" -gt 0 ]; then
    echo "deb_install_test: $failures check(s) failed"
    exit 1
fi
echo "deb_install_test: install, upgrades, remove and purge behave"
