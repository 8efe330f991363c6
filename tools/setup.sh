#!/usr/bin/env bash
# Installs everything fusion-pf and its tests need on a fresh Debian machine:
# python3-venv when Python cannot create a virtualenv (a stock Debian lacks it),
# system libraries (libusb for open3d/depthai, Chromium for the browser test),
# a virtualenv in .venv with the package and its extras, and the Node packages
# of the interop tests. Safe to run again: it skips what is already there.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
need_apt=()
# Debian ships venv/ensurepip apart from python3: python3-venv (and python3.X-venv for Python 3.X)
if ! "$PY" -c "import ensurepip, venv" >/dev/null 2>&1; then
  need_apt+=(python3-venv "python$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')-venv")
fi
dpkg -s libusb-1.0-0 >/dev/null 2>&1 || need_apt+=(libusb-1.0-0)
if [ "${1:-}" = "--test" ]; then
  command -v chromium >/dev/null 2>&1 || need_apt+=(chromium)
  command -v node >/dev/null 2>&1 || need_apt+=(nodejs npm)
fi
if [ ${#need_apt[@]} -gt 0 ]; then
  echo "setup: apt-get install ${need_apt[*]}"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || "$PY" -m venv .venv
extras="oak"
[ "${1:-}" = "--test" ] && extras="oak,dev"
.venv/bin/python -m pip install -q --upgrade pip
# tools/constraints.txt pins every Python package to the versions the last green fresh-clone CI ran
# with, on Python 3.11 (a new numpy once changed a float result and failed two tests); other Python
# versions resolve freely. To move to newer releases: in a fresh clone, delete it, run this script
# with --test, then `.venv/bin/python -m pip freeze --exclude-editable > tools/constraints.txt` and
# run the tests.
constraints=()
if [ -f tools/constraints.txt ] && [ "$(.venv/bin/python -c 'import sys; print(sys.version_info[:2] == (3, 11))')" = True ]; then
  constraints=(-c tools/constraints.txt)
fi
.venv/bin/python -m pip install -q "${constraints[@]}" -e ".[${extras}]"

if [ "${1:-}" = "--test" ] && [ -f tests/interop/package.json ]; then
  (cd tests/interop && npm ci --silent --no-audit --no-fund)
fi
