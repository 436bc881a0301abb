"""Rewrite the build-machine paths baked into the ROS 2 wheels' CMake exports.

The ROS 2 Kilted wheels on PyPI were built in a manylinux image; their
``share/*/cmake/*Export*.cmake`` files name that image's Python include
directory and numpy include directory. CMake refuses imported targets with
non-existent include paths, so building a rosidl message package against the
venv fails until these strings point at this interpreter's directories.
Idempotent; run with the venv's python.
"""

import pathlib
import sys
import sysconfig

import numpy

BUILD_PY_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
BUILD_NUMPY_INCLUDE = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def main() -> int:
    share = pathlib.Path(sys.prefix) / "share"
    py_include = sysconfig.get_paths()["include"]
    np_include = numpy.get_include()
    changed = 0
    for path in share.glob("*/cmake/*Export*.cmake"):
        text = path.read_text()
        if BUILD_PY_INCLUDE not in text and BUILD_NUMPY_INCLUDE not in text:
            continue
        text = text.replace(BUILD_NUMPY_INCLUDE, np_include).replace(BUILD_PY_INCLUDE, py_include)
        path.write_text(text)
        changed += 1
    print(f"fix_ros_wheel_cmake: rewrote {changed} CMake export file(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
