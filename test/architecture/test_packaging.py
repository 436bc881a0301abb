"""Packaging tells the truth: package.xml is valid REP-149 format 3 and declares what the code
imports, setup.py's requirements are the locked versions, the venv that `make setup` builds is
an ament prefix (as a colcon install space would be), and every noqa comment says why."""

from __future__ import annotations

import ast
import importlib.metadata as md
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCHEMA = REPO / "tools" / "schema" / "package_format3.xsd"
PACKAGE = "mems_emulator"
#: Python import name -> package.xml key (rosdep key or ROS package name)
IMPORT_KEYS = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "numba": "python3-numba",
    "matplotlib": "python3-matplotlib",
    "yaml": "python3-yaml",
    "tqdm": "python3-tqdm",
    "mcap": "mcap-ros2-support",
    "mcap_ros2": "mcap-ros2-support",
    # the compressors of MCAP chunks: no rosdep keys; mcap (from mcap-ros2-support) needs both
    "zstandard": "mcap-ros2-support",
    "lz4": "mcap-ros2-support",
    "rosbags": "python3-rosbags-pip",
    "rclpy": "rclpy",
    "rcl_interfaces": "rcl_interfaces",
    "builtin_interfaces": "builtin_interfaces",
    "ament_index_python": "ament_index_python",
    "std_msgs": "std_msgs",
    "sensor_msgs": "sensor_msgs",
    "geometry_msgs": "geometry_msgs",
    "std_srvs": "std_srvs",
    "diagnostic_msgs": "diagnostic_msgs",
    "rosgraph_msgs": "rosgraph_msgs",
    "mems_msgs": "mems_msgs",
    # foxglove-sdk has no rosdep key: setup.py and requirements.lock pin it (checked below)
    "foxglove": None,
    # the live view's front end in front of the SDK's server
    "websockets": "python3-websockets",
    # campaigns: pandas has a rosdep key; Dask and pyarrow have none (pinned like foxglove)
    "pandas": "python3-pandas",
    "dask": None,
    "distributed": None,
    "pyarrow": None,
}
STDLIB = set(sys.stdlib_module_names) | {"__future__"}
FIRST_PARTY = {"mems_sim", "mems_estimation", "mems_scenarios"}


def schema():
    import xmlschema

    return xmlschema.XMLSchema11(str(SCHEMA))


@pytest.mark.parametrize("manifest", ["package.xml", "msg_defs/package.xml"])
def test_package_xml_is_valid_format3(manifest):
    schema().validate(str(REPO / manifest))


def test_schema_refuses_a_broken_manifest():
    bad = (REPO / "package.xml").read_text().replace("<version>", "<version>v")
    assert not schema().is_valid(bad)
    no_license = re.sub(r"<license[^>]*>[^<]*</license>", "", (REPO / "package.xml").read_text())
    assert not schema().is_valid(no_license)


def imports_of(folder: str) -> set[str]:
    """Top-level modules imported anywhere in ``folder`` (third party and ROS only)."""
    found = set()
    for path in (REPO / folder).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.add(node.module.split(".")[0])
    return found - STDLIB - FIRST_PARTY


def declared(kinds: tuple[str, ...]) -> set[str]:
    root = ET.parse(REPO / "package.xml").getroot()
    return {e.text.strip() for e in root if e.tag in kinds}


def test_package_xml_declares_every_runtime_import():
    runtime = set()
    for pkg in FIRST_PARTY:
        runtime |= imports_of(pkg)
    unknown = runtime - set(IMPORT_KEYS)
    assert not unknown, f"imports without a package.xml key in IMPORT_KEYS: {sorted(unknown)}"
    keys = {IMPORT_KEYS[m] for m in runtime} - {None}
    missing = keys - declared(("exec_depend", "depend"))
    assert not missing, f"package.xml lacks exec_depend {sorted(missing)}"


def locked() -> dict[str, str]:
    pins = {}
    for line in (REPO / "requirements.lock").read_text().splitlines():
        if "==" in line and not line.startswith("#"):
            name, version = line.split("==")
            pins[name.lower().replace("_", "-")] = version
    return pins


def test_setup_requirements_are_the_locked_versions():
    reqs = md.requires(PACKAGE) or []
    assert reqs, "the installed distribution declares no requirements"
    pins = locked()
    for req in reqs:
        m = re.match(r"([A-Za-z0-9_.-]+)==([^;\s]+)", req)
        assert m, f"requirement not pinned: {req}"
        name, version = m.group(1).lower().replace("_", "-"), m.group(2)
        assert pins.get(name) == version, f"{req} differs from requirements.lock"
    names = {re.match(r"[A-Za-z0-9_.-]+", r).group(0).lower() for r in reqs}
    for module in (
        "numpy",
        "scipy",
        "numba",
        "matplotlib",
        "tqdm",
        "mcap",
        "rosbags",
        "foxglove-sdk",
        "websockets",
    ):
        assert module in names or module.replace("_", "-") in names, module


def test_make_venv_is_an_ament_prefix():
    """`make setup` leaves what a colcon install space has: the package in the ament index,
    share/<pkg> with the manifest, and every executable under lib/<pkg>."""
    from ament_index_python.packages import get_package_prefix, get_package_share_directory

    prefix = Path(get_package_prefix(PACKAGE))
    assert prefix == Path(sys.prefix)
    share = Path(get_package_share_directory(PACKAGE))
    for name in ("package.xml", "LICENSE", "CHANGELOG.rst"):
        assert (share / name).read_text() == (REPO / name).read_text(), name
    scripts = {
        ep.name for ep in md.distribution(PACKAGE).entry_points if ep.group == "console_scripts"
    }
    lib = prefix / "lib" / PACKAGE
    assert scripts and {p.name for p in lib.iterdir()} == scripts
    for exe in scripts:
        assert os.access(lib / exe, os.X_OK), exe
    run = subprocess.run(
        [str(lib / "mcap_info"), "--help"], capture_output=True, text=True, timeout=60
    )
    assert run.returncode == 0 and "usage" in run.stdout.lower(), run.stderr


NOQA = re.compile(r"#\s*noqa(?P<rest>.*)$")
NOQA_OK = re.compile(r"^:\s*[A-Z]+[0-9]+(\s*,\s*[A-Z]+[0-9]+)*\s+\S.*")


def test_every_noqa_names_its_rule_and_says_why():
    bad = []
    for path in REPO.rglob("*.py"):
        if any(part in {".venv", "build", "install", "log"} for part in path.parts):
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            m = NOQA.search(line)
            if m and not NOQA_OK.match(m.group("rest")):
                bad.append(f"{path.relative_to(REPO)}:{i}: {line.strip()}")
    assert not bad, "\n".join(bad)


def test_noqa_pattern():
    assert NOQA_OK.match(": E402  (path set up first)")
    assert not NOQA_OK.match(": E402")
    assert not NOQA_OK.match("")


def test_license_and_changelog_exist():
    assert "Apache License" in (REPO / "LICENSE").read_text()
    text = (REPO / "CHANGELOG.rst").read_text()
    version = ET.parse(REPO / "package.xml").getroot().findtext("version")
    assert version in text


def test_readme_is_an_entry_under_10_kb():
    """The README stays an entry (what it is, the two commands, layout, executables, links);
    references and notes live in docs/."""
    readme = (REPO / "README.md").read_bytes()
    assert len(readme) < 10_000, len(readme)
    text = readme.decode()
    for must in ("make demo", "make test", "Import rule", "docs/"):
        assert must in text, must
