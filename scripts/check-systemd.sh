#!/usr/bin/env bash
# Checks the systemd integration in systemd/: `systemd-analyze verify` on the unit (alone
# and with the CSI-camera drop-in), a dry run of the sysusers file, and the unit's exposure
# from `systemd-analyze security --offline=true`, failing above $MAX_EXPOSURE (3.0).
# Installs the `systemd` package when systemd-analyze is missing (idempotent).
#
# verify needs the unit's binary to exist, and the units it depends on by default
# (sysinit.target, ...): it runs with --root on a throwaway root holding a stub
# /usr/bin/jetpilot, a copy of this machine's unit directory and our unit, so nothing is
# installed on this machine and the unit is checked unchanged.
set -euo pipefail
cd "$(dirname "$0")/.."

MAX_EXPOSURE=${MAX_EXPOSURE:-3.0}
UNIT=systemd/jetpilot.service

if ! command -v systemd-analyze >/dev/null 2>&1; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends systemd >/dev/null
  echo "installed: systemd" >&2
fi
echo "== check-systemd: $(systemd-analyze --version | head -n 1)"

ROOT=$(mktemp -d)
trap 'rm -rf "$ROOT"' EXIT
mkdir -p "$ROOT/usr/bin" "$ROOT/lib/systemd" "$ROOT/etc/jetpilot" "$ROOT/usr/lib/sysusers.d"
cp -r "$(readlink -f /lib/systemd/system)" "$ROOT/lib/systemd/system"
printf '#!/bin/sh\nexit 0\n' >"$ROOT/usr/bin/jetpilot"
chmod 755 "$ROOT/usr/bin/jetpilot"
# The first-boot unit's commands, where Ubuntu 18.04 (JetPack 4.x) has them.
mkdir -p "$ROOT/bin"
for b in systemd-sysusers touch; do
  printf '#!/bin/sh\nexit 0\n' >"$ROOT/bin/$b"
  chmod 755 "$ROOT/bin/$b"
done
cp "$UNIT" "$ROOT/lib/systemd/system/jetpilot.service"
cp systemd/jetpilot-firstboot.service "$ROOT/lib/systemd/system/jetpilot-firstboot.service"
touch "$ROOT/etc/jetpilot/jetpilot.toml"

# verify exits 0 on warnings (unknown keys, bad values); any line about our unit fails.
verify() {
  local what=$1 unit=${2:-jetpilot.service} out
  if ! out=$(systemd-analyze verify --root="$ROOT" "$unit" 2>&1); then
    echo "$out" >&2
    echo "check-systemd: FAIL: systemd-analyze verify ($what)" >&2
    exit 1
  fi
  if grep -qi 'jetpilot' <<<"$out"; then
    echo "$out" >&2
    echo "check-systemd: FAIL: systemd-analyze verify warns about $what" >&2
    exit 1
  fi
  echo "verify $what: ok"
}
verify "$UNIT"
verify systemd/jetpilot-firstboot.service jetpilot-firstboot.service
mkdir -p "$ROOT/etc/systemd/system/jetpilot.service.d"
cp systemd/csi-camera.conf "$ROOT/etc/systemd/system/jetpilot.service.d/csi-camera.conf"
verify "$UNIT + systemd/csi-camera.conf"
cp systemd/gpio-motors.conf "$ROOT/etc/systemd/system/jetpilot.service.d/gpio-motors.conf"
verify "$UNIT + systemd/csi-camera.conf + systemd/gpio-motors.conf"
cp systemd/orin-gpu.conf "$ROOT/etc/systemd/system/jetpilot.service.d/orin-gpu.conf"
verify "$UNIT + systemd/csi-camera.conf + systemd/gpio-motors.conf + systemd/orin-gpu.conf"

cp systemd/jetpilot.sysusers.conf "$ROOT/usr/lib/sysusers.d/jetpilot.conf"
if ! out=$(systemd-sysusers --root="$ROOT" --dry-run 2>&1) || grep -qiE 'fail|error|ignor' <<<"$out"; then
  echo "$out" >&2
  echo "check-systemd: FAIL: systemd-sysusers dry run of systemd/jetpilot.sysusers.conf" >&2
  exit 1
fi
echo "sysusers systemd/jetpilot.sysusers.conf: ok ($(grep -c '^Creating' <<<"$out") users/groups)"

for s in systemd/debian/*; do
  sh -n "$s" || { echo "check-systemd: FAIL: $s is not valid sh" >&2; exit 1; }
done

security=$(systemd-analyze security --offline=true "$UNIT" 2>&1) || true
level=$(sed -n 's/.*Overall exposure level for [^:]*: \([0-9.]*\).*/\1/p' <<<"$security")
if [ -z "$level" ]; then
  echo "$security" >&2
  echo "check-systemd: FAIL: no exposure level from systemd-analyze security --offline=true" >&2
  exit 1
fi
grep '✗' <<<"$security" | sed 's/  */ /g' || true
echo "exposure of $UNIT: $level (limit $MAX_EXPOSURE)"
if ! awk -v l="$level" -v m="$MAX_EXPOSURE" 'BEGIN { exit !(l <= m) }'; then
  echo "check-systemd: FAIL: exposure $level > $MAX_EXPOSURE" >&2
  exit 1
fi
