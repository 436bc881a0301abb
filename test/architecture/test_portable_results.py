"""The same floats on another CPU: every numba kernel family, played on other targets.

``test/portable_probe.py`` runs each kernel family (device models, in-loop electronics,
filters, identification; the one-bit sigma-delta loop among them) on fixed inputs and
prints a digest of the raw outputs. Here it runs in subprocesses compiled for the host CPU
and for the targets of :data:`TARGETS` (the probe's ``--target``: numba's code generation
for another CPU on this one, ``generic`` x86-64 with SSE2 and an AVX2/FMA Haswell without
AVX-512; ``make setup`` fills their caches, so each run costs seconds), with
one and two numba threads, and with glibc's AVX-512 string and memory variants masked; the
digests must be equal bit for bit. A kernel compiled with fastmath reassociation (the
probe's ``deliberate_fastmath`` family) gives other floats for other vector widths: the
comparison sees it, so it would see a kernel of the project that did the same.

What stays outside (docs/testing.md): glibc's libm picks FMA variants of exp, sin, cos, log,
pow ... on CPUs with FMA, and their results differ in the last bit from the variants for
CPUs without it, so x86-64 CPUs without AVX2 and FMA are out of scope (checked below).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PROBE = REPO / "test" / "portable_probe.py"
#: numba targets besides the host (the Makefile's PORTABLE_TARGETS fill their caches).
TARGETS = ("generic", "haswell")
#: glibc hardware-capability masks for a run (GLIBC_TUNABLES), name -> value.
GLIBC_NO_AVX512 = "glibc.cpu.hwcaps=-AVX512F,-AVX512VL,-AVX512BW,-AVX512DQ,-AVX512CD"
GLIBC_NO_FMA = "glibc.cpu.hwcaps=-AVX2,-FMA"


def probe(*args: str, **env: str) -> dict[str, str]:
    """Digests per kernel family of one probe run with these environment changes."""
    environ = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU_")}
    environ.update(env)
    run = subprocess.run(
        [sys.executable, str(PROBE), *args],
        capture_output=True,
        text=True,
        env=environ,
        timeout=900,
        cwd=REPO,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout)


def families(digests: dict[str, str]) -> dict[str, str]:
    """The kernel families' digests (without the probe's own entries)."""
    return {k: v for k, v in digests.items() if not k.startswith("_")}


@pytest.fixture(scope="module")
def host() -> dict[str, str]:
    return probe("--deliberate-fastmath")


@pytest.mark.parametrize("target", TARGETS)
def test_kernels_give_the_same_floats_on_another_target(host, target):
    other = probe("--deliberate-fastmath", "--target", target)
    assert other["_numba_cpu"].startswith(target)
    ours, theirs = families(host), families(other)
    assert ours.keys() == theirs.keys()
    differ = sorted(k for k in ours if k != "deliberate_fastmath" and ours[k] != theirs[k])
    assert not differ, f"kernel families whose floats depend on the CPU target: {differ}"


def test_a_reassociated_kernel_is_caught():
    """The deliberate fastmath sum gives other floats on SSE2 (2 lanes) than on AVX2 (4
    lanes, FMA): the comparison above would fail for such a kernel."""
    generic = probe("deliberate_fastmath", "--target", "generic")
    haswell = probe("deliberate_fastmath", "--target", "haswell")
    assert generic["deliberate_fastmath"] != haswell["deliberate_fastmath"]


def test_kernels_give_the_same_floats_with_one_and_two_threads(host):
    one = probe(NUMBA_NUM_THREADS="1")
    two = probe(NUMBA_NUM_THREADS="2")
    assert families(one) == families(two)
    assert families(one) == {k: v for k, v in families(host).items() if k in families(one)}


def test_kernels_give_the_same_floats_with_glibc_avx512_masked(host):
    masked = probe(GLIBC_TUNABLES=GLIBC_NO_AVX512)
    assert families(masked) == {k: v for k, v in families(host).items() if k in families(masked)}


def test_cpus_without_fma_are_out_of_scope():
    """glibc's libm without its FMA variants rounds some results differently: a CPU without
    FMA would record other floats, which is why such CPUs are out of scope (docs/testing.md).
    If this starts to pass (a libm that is correctly rounded), the scope can widen."""
    fma = probe("_libm")
    no_fma = probe("_libm", GLIBC_TUNABLES=GLIBC_NO_FMA)
    assert fma["_libm"] != no_fma["_libm"]


def test_host_figures_are_compared_by_place_not_value():
    from reference_rule import figures_difference

    ref = [{"name": "graph.wall_time", "value": 7.6, "unit": "s", "target": None, "pass": None}]
    assert figures_difference([dict(ref[0], value=11.2)], ref) is None
    assert figures_difference([dict(ref[0], unit="ms")], ref) is not None
    moved = [dict(ref[0], name="graph.omega_rmse", value=11.2)]
    assert figures_difference(moved, [dict(moved[0], value=7.6)]) is not None
