#!/usr/bin/env bash
# Debian packages boomtip needs at run time: Open3D's shared libraries, and python3-venv
# where the system Python lacks ensurepip; with --test also Chromium, in which the tests look at
# rerun's web viewer. Installs only what is missing.
set -euo pipefail
need=()
pkgs=(libusb-1.0-0 libgl1 libegl1 libgomp1)
[ "${1:-}" = "--test" ] && pkgs+=(chromium)
for pkg in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need+=("$pkg")
done
PY="${PYTHON:-python3}"
"$PY" -c "import ensurepip, venv" 2>/dev/null || need+=("python3-venv")
if [ ${#need[@]} -eq 0 ]; then
  exit 0
fi
echo "installing Debian packages: ${need[*]}"
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${need[@]}"
