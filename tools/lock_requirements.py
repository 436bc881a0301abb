"""Write requirements.lock: the exact version of every distribution in the venv.

Run with the venv's python after installing or upgrading a dependency. Only
``*.dist-info`` distributions are listed: the ROS 2 wheels also leave
``*.egg-info`` metadata of their ament packages (``action_msgs`` for the wheel
``ros-action-msgs``) whose names are not installable from PyPI.
"""

import importlib.metadata as md
import pathlib
import sys

SKIP = {"pip", "mems-emulator", "mems_emulator"}


def main() -> int:
    pins = {}
    for dist in md.distributions():
        if not str(getattr(dist, "_path", "")).endswith(".dist-info"):
            continue
        name = dist.metadata["Name"]
        if name.lower() not in SKIP:
            pins[name.lower()] = f"{name}=={dist.version}"
    lines = [
        "# Exact versions of everything `make setup` installs into .venv (CPython 3.11, x86_64).",
        "# Regenerate with `.venv/bin/python tools/lock_requirements.py` after changing a dependency.",
    ]
    lines += [pins[k] for k in sorted(pins)]
    out = pathlib.Path(__file__).resolve().parents[1] / "requirements.lock"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out} ({len(pins)} pins)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
