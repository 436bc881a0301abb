"""Allan figure labels show every value with its significant digits."""

from __future__ import annotations

from mems_estimation.identification.imu_noise_plots import term_labels
from mems_sim.table import significant


def test_labels_keep_significant_digits_of_short_and_long_times():
    white, walk, markov = term_labels(2.1e-4, 3.3e-6, 3.4e-4, 0.376)
    assert markov == "Gauss-Markov B=0.00034, T=0.376 s"  # was "T=0 s"
    assert white == "N/√τ, N=0.00021" and walk == "K√(τ/3), K=3.3e-06"
    assert term_labels(1.0, 1.0, 1.0, 119.4)[2].endswith("T=119 s")
    assert term_labels(1.0, 1.0, 1.0, 12345.0)[2].endswith("T=1.23e+04 s")


def test_significant_digits():
    assert [significant(v) for v in (0.376, 119.3, 0.0, 1.23456e-9)] == [
        "0.376",
        "119",
        "0",
        "1.23e-09",
    ]
    assert significant(0.37649, digits=4) == "0.3765"
