"""numpy's and OpenBLAS's kernel choice is pinned for every way the package runs
(docs/testing.md, "The same floats on every CPU")."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mems_sim import cpu_pins

REPO = Path(__file__).resolve().parents[2]
CHECK = (
    "import os, sys; import numpy; from mems_sim.cpu_pins import PINS, pins_in_effect; "
    "print(pins_in_effect(), all(os.environ.get(k) == v for k, v in PINS.items()))"
)


def _clean_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in cpu_pins.PINS}


def _has_avx512() -> bool:
    try:
        return " avx512f " in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


def test_the_makefile_exports_the_package_pins():
    text = (REPO / "Makefile").read_text()
    exported = dict(re.findall(r"^export (\w+) := (.*)$", text, flags=re.M))
    assert {k: exported.get(k) for k in cpu_pins.PINS} == cpu_pins.PINS


@pytest.mark.parametrize("first", ["mems_sim", "mems_estimation.identification.allan"])
def test_importing_the_package_first_pins_numpy(first):
    code = f"import {first}; " + CHECK
    run = subprocess.run(
        [sys.executable, "-c", code], env=_clean_env(), capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["True", "True"]


def test_an_executable_runs_under_the_pins():
    """A console script (what users and ``ros2 run`` start) imports the package first."""
    script = Path(sys.executable).parent / "mcap_info"
    code = (
        f"import runpy, sys; sys.argv = ['mcap_info', '--help']\n"
        f"try:\n    runpy.run_path({str(script)!r}, run_name='__main__')\n"
        f"except SystemExit:\n    pass\n" + CHECK
    )
    run = subprocess.run(
        [sys.executable, "-c", code], env=_clean_env(), capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[-2:] == ["True", "True"]


@pytest.mark.skipif(not _has_avx512(), reason="the CPU has no AVX-512 kernels to pin away")
def test_numpy_loaded_first_is_reported():
    code = "import numpy; import mems_sim; from mems_sim.cpu_pins import pins_in_effect; "
    code += "print(pins_in_effect())"
    run = subprocess.run(
        [sys.executable, "-c", code], env=_clean_env(), capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["False"]
