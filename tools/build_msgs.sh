#!/usr/bin/env bash
# Build the interface package msg_defs/ (mems_msgs) with rosidl against the
# ROS 2 wheels in the venv and install it into the venv prefix, so that
# `from mems_msgs.msg import AdcFrame` works with the venv's python.
set -euo pipefail
VENV=${VENV:-.venv}
VENV=$(cd "$VENV" && pwd)
BUILD=${BUILD_DIR:-build/mems_msgs}
mkdir -p "$(dirname "$BUILD")"
"$VENV/bin/python" tools/fix_ros_wheel_cmake.py
export CMAKE_PREFIX_PATH="$VENV" AMENT_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH"
cmake -S msg_defs -B "$BUILD" -DCMAKE_INSTALL_PREFIX="$VENV" \
  -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
  -DCMAKE_BUILD_TYPE=Release -Wno-dev > "$BUILD.configure.log" 2>&1 \
  || { cat "$BUILD.configure.log"; exit 1; }
cmake --build "$BUILD" -j2 > "$BUILD.build.log" 2>&1 || { tail -50 "$BUILD.build.log"; exit 1; }
cmake --install "$BUILD" > "$BUILD.install.log" 2>&1 || { tail -50 "$BUILD.install.log"; exit 1; }
echo "build_msgs: mems_msgs installed into $VENV"
