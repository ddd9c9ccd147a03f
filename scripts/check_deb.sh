#!/usr/bin/env bash
# Checks a roomcal .deb (from `cargo deb`) without installing it: the files it ships and their
# modes, the control fields, the conffiles, the maintainer scripts (shellcheck when present),
# the unit (systemd-analyze verify when present) and the packaged binary itself (it runs, it
# is this version, it was built with `v4l2`). One line per check; exit 1 on any failure.
#
#   scripts/check_deb.sh target/debian/roomcal_0.1.0-1_amd64.deb
set -euo pipefail
cd "$(dirname "$0")/.."

deb=${1:?usage: scripts/check_deb.sh PACKAGE.deb}
[ -f "$deb" ] || { echo "check_deb: $deb: no such file" >&2; exit 1; }
version=$(sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n 1)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
failures=0

pass() { echo "ok    $*"; }
fail() { echo "FAIL  $*"; failures=$((failures + 1)); }
check() { # check DESCRIPTION COMMAND...: passes when the command succeeds
    local what=$1
    shift
    if "$@"; then pass "$what"; else fail "$what"; fi
}

dpkg-deb -c "$deb" >"$work/contents"
dpkg-deb -e "$deb" "$work/control"
dpkg-deb -x "$deb" "$work/root"

# `dpkg-deb -c` lines: mode owner/group size date time ./path
ships() { # ships MODE PATH
    awk -v mode="$1" -v path="./$2" '$1 == mode && ($2 == "root/root" || $2 == "0/0") && $6 == path { found = 1 }
        END { exit !found }' "$work/contents"
}
for entry in "-rwxr-xr-x usr/bin/roomcal" \
    "-rw-r--r-- lib/systemd/system/roomcal.service" \
    "-rw-r--r-- etc/roomcal/roomcal.toml" \
    "-rw-r--r-- etc/roomcal/room.toml" \
    "-rw-r--r-- usr/share/doc/roomcal/README.md" \
    "-rw-r--r-- usr/share/doc/roomcal/docs/install.md" \
    "-rw-r--r-- usr/share/doc/roomcal/docs/daemon.md" \
    "-rw-r--r-- usr/share/doc/roomcal/docs/service.md" \
    "-rw-r--r-- usr/share/doc/roomcal/copyright"; do
    check "ships ${entry#* } (${entry%% *}, owned by root)" ships "${entry%% *}" "${entry#* }"
done
# The secret is per vehicle and the store the vehicle's own: neither may come in a package.
check "ships no secret and nothing in the store" \
    bash -c "! grep -Eq '\./etc/roomcal/secret|\./var/lib/roomcal/.' '$work/contents'"
check "the packaged configs are the repository's" \
    bash -c "cmp -s '$work/root/etc/roomcal/roomcal.toml' config/roomcal.toml \
        && cmp -s '$work/root/etc/roomcal/room.toml' config/room.toml"
check "the packaged documentation is the repository's" \
    bash -c "cmp -s '$work/root/usr/share/doc/roomcal/README.md' README.md \
        && for page in install daemon service; do \
            cmp -s \"$work/root/usr/share/doc/roomcal/docs/\$page.md\" docs/\$page.md || exit 1; done"
check "the packaged unit is the repository's" \
    cmp -s "$work/root/lib/systemd/system/roomcal.service" systemd/roomcal.service

field() { dpkg-deb -f "$deb" "$1"; }
check "Package: roomcal" test "$(field Package)" = roomcal
check "Version: $version-N" bash -c "[[ '$(field Version)' == '$version'-* ]]"
check "Architecture: $(dpkg --print-architecture)" \
    test "$(field Architecture)" = "$(dpkg --print-architecture)"
check "Maintainer set ($(field Maintainer))" test -n "$(field Maintainer)"
check "Depends names libc6 and passwd ($(field Depends))" \
    bash -c "grep -q 'libc6' <<<'$(field Depends)' && grep -Eq '(^|, )passwd' <<<'$(field Depends)'"

check "conffiles: exactly /etc/roomcal/roomcal.toml and room.toml" \
    test "$(sort "$work/control/conffiles" | tr '\n' ' ')" = \
    "/etc/roomcal/room.toml /etc/roomcal/roomcal.toml "
for script in postinst prerm postrm; do
    check "maintainer script $script is executable" test -x "$work/control/$script"
done
if command -v shellcheck >/dev/null; then
    check "maintainer scripts shellcheck-clean" \
        shellcheck "$work/control/postinst" "$work/control/prerm" "$work/control/postrm"
else
    echo "skip  shellcheck: not installed"
fi

bin=$work/root/usr/bin/roomcal
check "the packaged binary runs and is $version" \
    bash -c "[ \"\$('$bin' --version)\" = 'roomcal $version' ]"
# Its symbols belong in the -dbgsym package: a 50 MB binary on a vehicle is debug info.
if command -v readelf >/dev/null; then
    check "the packaged binary is stripped (no .debug_info)" \
        bash -c "! readelf -S '$bin' | grep -q '\.debug_info'"
else
    echo "skip  stripped binary: readelf not installed"
fi
# The daemon's default camera is v4l2:/dev/video0; without the feature the binary carries
# this refusal instead of a driver.
check "the packaged binary was built with feature v4l2" \
    bash -c "! grep -aq 'roomcal was built without feature' '$bin'"

if command -v systemd-analyze >/dev/null; then
    # The unit as packaged, its ExecStart pointed at the extracted binary (verify checks
    # that the command exists); any diagnostic at all fails the check.
    sed "s#^ExecStart=/usr/bin/roomcal #ExecStart=$bin #" \
        "$work/root/lib/systemd/system/roomcal.service" >"$work/roomcal.service"
    if systemd-analyze verify "$work/roomcal.service" >"$work/verify" 2>&1 \
        && [ ! -s "$work/verify" ]; then
        pass "systemd-analyze verify roomcal.service"
    else
        fail "systemd-analyze verify roomcal.service: $(tr '\n' ' ' <"$work/verify")"
    fi
else
    echo "skip  systemd-analyze: not installed"
fi

if [ "$failures" -gt 0 ]; then
    echo "check_deb: $failures check(s) failed on $deb"
    exit 1
fi
echo "check_deb: $deb is complete"
