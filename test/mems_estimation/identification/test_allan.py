"""Tests of the overlapping Allan deviation (mems_estimation.identification.allan), no ROS."""

import contextlib
import io
import math
import os
import sys

import allantools
import numpy as np
import pytest

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", "..")))

from mems_estimation.identification.allan import (
    allan_analysis,
    chi2_interval,
    edf_from_slope,
    edf_greenhall,
    edf_oadev,
    oadev,
    tau_grid,
)


def _datasets():
    rng = np.random.default_rng(7)
    yield "white", rng.standard_normal(5000) * 0.3 + 1.7, 100.0
    yield "random_walk", np.cumsum(rng.standard_normal(4097)) * 1e-3, 50.0
    yield (
        "mixed_odd",
        rng.standard_normal(20001) + np.cumsum(rng.standard_normal(20001)) * 0.01,
        100.0,
    )
    yield "tiny", rng.standard_normal(9), 1.0


@pytest.mark.parametrize("kind", ["octave", "decade", "all"])
def test_equals_allantools(kind):
    for name, y, fs in _datasets():
        ref = allantools.oadev(y, rate=fs, data_type="freq", taus=kind)
        got = oadev(y, fs, kind)
        assert np.array_equal(got[0], ref[0]), (name, got[0], ref[0])
        assert np.array_equal(got[3], ref[3]), name
        assert np.max(np.abs(got[1] / ref[1] - 1.0)) < 1e-9, name
        assert np.max(np.abs(got[2] / ref[2] - 1.0)) < 1e-9, name


def test_equals_allantools_explicit_taus():
    rng = np.random.default_rng(3)
    y = rng.standard_normal(3000)
    taus = np.array([0.01, 0.013, 0.5, 0.5, 2.0, 14.99, 15.0, 40.0])
    ref = allantools.oadev(y, rate=100.0, data_type="freq", taus=taus)
    got = oadev(y, 100.0, taus)
    assert np.array_equal(got[0], ref[0])
    assert np.max(np.abs(got[1] / ref[1] - 1.0)) < 1e-9


# allantools' 'all' grid costs O(n^2): compared up to 12345 samples only.
GRID_CASES = [
    (n, k)
    for n in (9, 1000, 1023, 1024, 12345, 10**6)
    for k in ("octave", "decade", "all")
    if not (k == "all" and n > 20000)
]


@pytest.mark.parametrize("n, kind", GRID_CASES)
def test_tau_grid_matches_allantools(n, kind):
    fs = 100.0
    y = np.zeros(n)
    y[::2] = 1.0
    ref = allantools.oadev(y, rate=fs, data_type="freq", taus=kind)[0]
    assert np.array_equal(tau_grid(n, fs, kind), ref)


def test_tau_grid_octave_limit():
    taus = tau_grid(10**6, 100.0, "octave")
    m = np.round(taus * 100.0)
    assert m[0] == 1 and m[-1] == 2**18 and np.all(np.diff(np.log2(m)) == 1)
    with pytest.raises(ValueError, match="tau grid"):
        tau_grid(100, 1.0, "weekly")


def test_white_noise_analytic():
    """White rate noise of density N: AVAR = N^2 / tau (IEEE 952 Annex C)."""
    fs, n, N = 100.0, 400_000, 2e-3
    y = np.random.default_rng(5).standard_normal(n) * N * np.sqrt(fs)
    res = allan_analysis(y, fs, "octave", confidence=0.95)
    theory = N / np.sqrt(res.taus)
    sel = res.edf > 20
    assert sel.sum() >= 12
    tol = 4.0 * np.sqrt(1.0 / (2.0 * res.edf[sel]))  # 4 sd of an ADEV estimate
    assert np.all(np.abs(res.adev[sel] / theory[sel] - 1) < tol)
    inside = (res.ci_low <= theory) & (theory <= res.ci_high)
    assert inside.mean() >= 0.8


def test_edf_and_chi2_interval():
    N = 10001
    # white FM at m = 1 (Howe-Allan-Barnes approximation): about 3(N-1)/2 * 4/9
    assert edf_oadev(N, 1, 0) == pytest.approx((1.5 * (N - 1) - 2 * (N - 2) / N) * 4 / 9)
    m = np.array([1, 10, 100])
    assert edf_from_slope(N, m, np.full(3, -1.0)) == pytest.approx(
        [edf_greenhall(0, 2, k, N) for k in m]
    )
    mid = edf_from_slope(N, np.array([100]), np.array([-0.5]))[0]
    assert mid == pytest.approx(
        math.sqrt(edf_greenhall(0, 2, 100, N) * edf_greenhall(-1, 2, 100, N))
    )
    lo, hi = chi2_interval(1.0, 10.0, 0.95)
    assert lo < 1.0 < hi and lo == pytest.approx(10 / 20.483, rel=1e-3)


@pytest.mark.parametrize("alpha", [2, 1, 0, -1, -2])
def test_edf_greenhall_equals_allantools(alpha):
    """Greenhall & Riley (2003) edf equals allantools.edf_greenhall (Stable32's algorithm)."""
    for n_phase in (101, 1001, 100_001):
        for m in (1, 3, 16, 40, 1000, 2**14):
            if n_phase - 2 * m < 2:
                continue
            for overlapping in (True, False):
                for d in (2, 3):
                    if alpha + 2 * d <= 1 or n_phase < 1 + m * (d + 1):
                        continue
                    with contextlib.redirect_stdout(io.StringIO()):
                        try:
                            ref = allantools.edf_greenhall(alpha, d, m, n_phase, overlapping)
                        except NotImplementedError:
                            continue
                    got = edf_greenhall(alpha, d, m, n_phase, overlapping)
                    assert got == pytest.approx(ref, rel=1e-6), (alpha, d, m, n_phase)
