#!/usr/bin/env bash
# System prerequisites of `make setup` on Debian 12: Python 3.11 with venv,
# a C/C++ compiler and CMake (rosidl generates and compiles C typesupport for
# the interface package). Installs what is missing with apt-get when run as
# root; otherwise names the missing packages and stops.
set -euo pipefail
PYTHON=${PYTHON:-python3}
missing=()
command -v cmake >/dev/null || missing+=(cmake)
command -v g++ >/dev/null || missing+=(g++)
command -v gcc >/dev/null || missing+=(gcc)
command -v make >/dev/null || missing+=(make)
if ! command -v "$PYTHON" >/dev/null; then
  missing+=(python3 python3-venv python3-dev)
else
  "$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' || {
    echo "bootstrap: $PYTHON is $("$PYTHON" -V 2>&1); the ROS 2 Kilted wheels need CPython 3.11" >&2
    exit 1; }
  "$PYTHON" -c 'import ensurepip, venv' 2>/dev/null || missing+=(python3-venv)
  "$PYTHON" -c 'import sysconfig, os, sys; sys.exit(0 if os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")) else 1)' || missing+=(python3-dev)
fi
if [ ${#missing[@]} -eq 0 ]; then exit 0; fi
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  echo "bootstrap: installing ${missing[*]} with apt-get"
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}"
else
  echo "bootstrap: missing system packages: ${missing[*]} (sudo apt-get install ${missing[*]})" >&2
  exit 1
fi
