#!/bin/sh
# Open3D's Linux wheels link against these system libraries; pip cannot install them.
set -eu
PKGS="libusb-1.0-0 libegl1 libgl1"

command -v dpkg-query >/dev/null 2>&1 || {
    echo "slamcli: not a Debian/Ubuntu system; make sure libusb-1.0, libEGL and libGL are installed." >&2
    exit 0
}
missing=""
for p in $PKGS; do
    status=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
    case "$status" in
        *"install ok installed"*) ;;
        *) missing="$missing $p" ;;
    esac
done
[ -z "$missing" ] && exit 0

if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "slamcli: installing system libraries Open3D needs:$missing"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    # shellcheck disable=SC2086
    apt-get install -y -qq --no-install-recommends $missing >/dev/null
else
    echo "slamcli: Open3D needs system libraries that are missing:$missing" >&2
    echo "Install them with:  sudo apt-get install$missing" >&2
    exit 1
fi
