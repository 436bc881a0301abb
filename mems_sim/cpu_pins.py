"""The same floats on every x86-64 CPU with AVX2 and FMA: numpy's and OpenBLAS's kernel choice.

numpy and OpenBLAS pick their kernels by the CPU when they load. Their AVX-512 kernels
round differently from the AVX2 ones (numpy's sums and SVML-based sin/cos/exp/log,
OpenBLAS's SkylakeX and Zen dot and matrix kernels), which moves a result in its last
bits and a one-bit sigma-delta loop's decisions with it; OpenBLAS also splits a long dot
product over its threads, so the sum's order would follow the machine's core count. The
package's ``__init__`` calls :func:`apply` before anything imports numpy, so every
executable of the package (console scripts, ``ros2 run``, ``python -m``) runs with:

* ``NPY_DISABLE_CPU_FEATURES`` = :data:`NUMPY_DISABLED`: numpy's AVX2/FMA3 kernels even on
  an AVX-512 CPU (naming a feature the CPU lacks is harmless);
* ``OPENBLAS_CORETYPE`` = ``Haswell``: OpenBLAS's AVX2 kernels (numpy's and scipy's
  bundled copies both read it);
* ``OPENBLAS_NUM_THREADS`` = ``1``: no reduction split over threads.

A value the user set is kept (``setdefault``). Both libraries read the variables once, when
they load: a program that imported numpy before this package keeps the kernels it got;
:func:`pins_in_effect` tells. docs/testing.md states the whole rule (glibc's libm and
CPUs without FMA, aarch64).
"""

from __future__ import annotations

import os
import sys

#: numpy's dispatch targets above AVX2/FMA3 (numpy 2.x names), disabled.
NUMPY_DISABLED = "X86_V4 AVX512_ICL AVX512_SPR"
#: Environment defaults applied by :func:`apply`.
PINS = {
    "NPY_DISABLE_CPU_FEATURES": NUMPY_DISABLED,
    "OPENBLAS_CORETYPE": "Haswell",
    "OPENBLAS_NUM_THREADS": "1",
}


def apply(environ=None) -> None:
    """Set every pin of :data:`PINS` that the environment does not set yet."""
    env = os.environ if environ is None else environ
    for name, value in PINS.items():
        env.setdefault(name, value)


def pins_in_effect() -> bool:
    """True if numpy either is not loaded yet or loaded under the pins (no AVX-512 kernel)."""
    if "numpy" not in sys.modules:
        return True
    from numpy._core._multiarray_umath import __cpu_features__

    return not any(__cpu_features__.get(name, False) for name in NUMPY_DISABLED.split())
