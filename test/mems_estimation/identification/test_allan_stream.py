"""Tests of the streaming overlapping Allan sums (mems_estimation.identification.allan_stream),
no ROS: equal to the whole-array estimator, thinned above exact_m_max, bounded memory."""

import numpy as np
import pytest

from mems_estimation.identification.allan import oadev
from mems_estimation.identification.allan_stream import StreamingAllan


def _feed(st, y, seed=0):
    rng = np.random.default_rng(seed)
    i = 0
    while i < y.shape[0]:
        k = int(rng.integers(1, 20_000))
        st.add(y[i : i + k])
        i += k


def test_streaming_equals_batch():
    """Streaming sums (bounded memory) equal the batch oadev to 1e-12 relative."""
    rng = np.random.default_rng(11)
    n = 150_001
    y = rng.standard_normal(n) * 0.05 + np.cumsum(rng.standard_normal(n)) * 1e-4 + 9.81
    for kind in ("octave", "decade"):
        st = StreamingAllan(2, 100.0, kind)
        _feed(st, np.column_stack([y, 2.0 * y]))
        taus, adev, nt = st.adev()
        ref = oadev(y, 100.0, kind)
        assert np.array_equal(taus, ref[0]) and np.array_equal(nt, ref[3])
        assert np.max(np.abs(adev[0] / ref[1] - 1.0)) < 1e-12, kind
        assert np.max(np.abs(adev[1] / (2.0 * ref[1]) - 1.0)) < 1e-12, kind
        assert st.mean()[0] == pytest.approx(y.mean(), rel=1e-13)
        whole = StreamingAllan(2, 100.0, kind)  # the split into calls does not matter
        whole.add(np.column_stack([y, 2.0 * y]))
        assert np.array_equal(whole.adev()[1], adev) and np.array_equal(whole.mean(), st.mean())
    assert st.nbytes() < 60e6


def test_streaming_thinned_large_m():
    """Above exact_m_max the sum runs over every s-th k (s = smallest divisor with m/s <= 4096)."""
    rng = np.random.default_rng(2)
    y = rng.standard_normal(60_000) + np.cumsum(rng.standard_normal(60_000)) * 1e-2
    st = StreamingAllan(1, 10.0, "octave", exact_m_max=64)
    _feed(st, y[:, None], seed=1)
    taus, adev, nt = st.adev()
    phase = np.concatenate([[0.0], np.cumsum(y - y.mean())])
    for m, a, k in zip(np.round(taus * 10.0).astype(int), adev[0], nt):
        s = 1 if m <= 4096 else next(d for d in range(-(-m // 4096), m + 1) if m % d == 0)
        x = phase[::s]
        r = m // s
        d2 = x[2 * r :] - 2 * x[r:-r] + x[: -2 * r]
        assert k == d2.size
        assert a == pytest.approx(np.sqrt(np.sum(d2**2) / (2 * d2.size)) / m, rel=1e-12)
    big = StreamingAllan(6, 100.0, "octave")
    assert big.nbytes() < 60e6  # independent of the record length
