"""Make the venv an ament prefix for this package, as `colcon build` makes an install space.

`pip install -e .` (what `make setup` runs, so that edits take effect without reinstalling)
installs the package's modules and console scripts but skips setup.py's ``data_files``. This
script adds what colcon's install would: the package's marker in the ament resource index,
``share/<pkg>/`` (package.xml, LICENSE, CHANGELOG.rst, launch and config files if any) and
``lib/<pkg>/<executable>`` for every console script (symbolic links to the venv's ``bin/``),
so that `ros2 run`-style lookups (``get_package_prefix`` + ``lib/<pkg>/<exe>``) and
``get_package_share_directory`` work in the venv. Run with the venv's python; idempotent.
"""

from __future__ import annotations

import importlib.metadata as md
import shutil
import sys
from pathlib import Path

PACKAGE = "mems_emulator"
REPO = Path(__file__).resolve().parents[1]
SHARE_FILES = ("package.xml", "LICENSE", "CHANGELOG.rst")
SHARE_DIRS = ("launch", "config")


def console_scripts(dist_name: str = PACKAGE) -> list[str]:
    """Names of the console scripts the installed distribution declares."""
    dist = md.distribution(dist_name)
    return sorted(ep.name for ep in dist.entry_points if ep.group == "console_scripts")


def install(prefix: Path) -> list[Path]:
    """Write the ament index marker, share/<pkg> and lib/<pkg> into ``prefix``."""
    written = []
    index = prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE
    index.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(REPO / "resource" / PACKAGE, index)
    written.append(index)
    share = prefix / "share" / PACKAGE
    share.mkdir(parents=True, exist_ok=True)
    for name in SHARE_FILES:
        shutil.copyfile(REPO / name, share / name)
        written.append(share / name)
    for name in SHARE_DIRS:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, share / name, dirs_exist_ok=True)
            written.append(share / name)
    lib = prefix / "lib" / PACKAGE
    if lib.exists():
        shutil.rmtree(lib)  # no link left behind for a renamed executable
    lib.mkdir(parents=True)
    for exe in console_scripts():
        target = prefix / "bin" / exe
        if not target.exists():
            raise SystemExit(f"install_ament_prefix: {target} is missing (pip install -e . first)")
        (lib / exe).symlink_to(Path("..", "..", "bin", exe))
        written.append(lib / exe)
    return written


def main() -> int:
    written = install(Path(sys.prefix))
    print(
        f"install_ament_prefix: {PACKAGE} in the ament index of {sys.prefix} ({len(written)} files)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
