"""Piezo actuator hysteresis (Bouc-Wen) and creep: against an independent ODE solution,
the loop's closed form, the creep laws, the linear piezo and the parameter table.

Equation labels (H1)-(H6), (C1)-(C3) are those of :mod:`mems_sim.hardware.piezo_hysteresis`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mems_sim.hardware import piezo_hysteresis as ph
from mems_sim.params import ParameterError

#: The stage's drive: sample rate [Hz], drive frequency [Hz], top amplitude [V].
FS, F_DRIVE, U_TOP = 625_000.0, 1700.0, 1.3
#: The stage's quasi-static tilt per volt, b_c / wn^2 [rad/V] (Chen 2018 Table 3.3).
GAIN = 3782.5 / (2.0 * math.pi * 1714.5) ** 2
NO_CREEP = {"creep_per_decade": 0.0}
#: A second loop shape: n = 2 (the RK4 path of (H3)).
N2 = {"bw_alpha": 0.3, "bw_beta": 0.6, "bw_gamma": 0.2, "bw_n": 2.0, **NO_CREEP}
HYST_OFF = {"bw_alpha": 0.0, "bw_beta": 0.0, "bw_gamma": 0.0}


def bits(a: np.ndarray) -> np.ndarray:
    """The float64 bit patterns (so -0.0 and 0.0 differ)."""
    return np.ascontiguousarray(a, dtype=float).view(np.uint64)


def drive(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smooth two-tone drive u(t) [V] with minor loops, and du/dt [V/s]."""
    w1, w2 = 2.0 * math.pi * F_DRIVE, 2.0 * math.pi * 3.3 * F_DRIVE
    u = 0.2 + 1.0 * np.sin(w1 * t) + 0.3 * np.sin(w2 * t + 0.4)
    du = 1.0 * w1 * np.cos(w1 * t) + 0.3 * w2 * np.cos(w2 * t + 0.4)
    return u, du


def ivp_z(p: dict, t_eval: np.ndarray) -> np.ndarray:
    """z(t) [V] of the time-domain Bouc-Wen ODE (H2) under :func:`drive`, by scipy."""
    a, b, g, n = p["bw_alpha"], p["bw_beta"], p["bw_gamma"], p["bw_n"]

    def rhs(t, z):
        _, du = drive(np.array([t]))
        az = abs(z[0])
        return [a * du[0] - b * abs(du[0]) * az ** (n - 1.0) * z[0] - g * du[0] * az**n]

    sol = solve_ivp(
        rhs, (0.0, t_eval[-1]), [0.0], method="DOP853", t_eval=t_eval, rtol=1e-11, atol=1e-14
    )
    assert sol.success, sol.message
    return sol.y[0]


def loop_scale(p: dict) -> float:
    """The default loop's width in z [V]: 2 w_mid at the stage's top drive, (H6)."""
    z = ph.loop_peak_z(p, U_TOP)
    return 2.0 * ph.loop_width(p, U_TOP) * (U_TOP - z)


# ------------------------------------------------------------------- 1. against solve_ivp
@pytest.mark.parametrize("overrides", [NO_CREEP, N2], ids=["n1_exact", "n2_rk4"])
def test_hysteresis_matches_an_independent_ode_solution(overrides):
    """h of the sampled model vs the ODE (H2) with the smooth drive, over 4 periods at the
    stage's rate and at 10x that rate. The only error is the cut turning points (module
    doc): second order in 1/fs (how much depends on where each turn falls between two
    samples), at most 1e-3 of the loop width at the stage's rate and 1e-5 at 10x, and more
    than 20x smaller at 10x the rate."""
    p = ph.piezo_values(overrides)
    width = loop_scale(ph.piezo_values(NO_CREEP))
    t_end = 4.0 / F_DRIVE
    dev = {}
    for fs in (FS, 10.0 * FS):
        t = np.arange(int(t_end * fs)) / fs
        u, _ = drive(t)
        act = ph.PiezoActuator(overrides, gain=GAIN, sample_rate_hz=fs, u0=float(u[0]))
        h = act.step(u).h
        dev[fs] = np.max(np.abs(h - GAIN * ivp_z(p, t))) / (GAIN * width)
    assert dev[FS] < 1e-3, dev
    assert dev[10.0 * FS] < 1e-5, dev
    assert dev[10.0 * FS] < dev[FS] / 20.0, dev  # the cut turns' second order


# ------------------------------------------------------------------- 2. loop width
def periodic_loop(overrides: dict, amp: float, per_period: int, periods: int = 12):
    """(u, x, h) of the last period of a sinusoid of amplitude ``amp`` [V]."""
    u = amp * np.sin(2.0 * math.pi * np.arange(per_period * periods) / per_period)
    fr = ph.PiezoActuator(overrides, gain=GAIN).step(u)
    return u[-per_period:], fr.x[-per_period:], fr.h[-per_period:]


def measured_width(u: np.ndarray, x: np.ndarray) -> float:
    """Largest gap between descending and ascending branch / (max x - min x)."""
    up = np.diff(u, prepend=u[-1]) > 0.0
    grid = np.linspace(u.min(), u.max(), 4001)[1:-1]
    branches = []
    for sel in (up, ~up):
        order = np.argsort(u[sel])
        branches.append(np.interp(grid, u[sel][order], x[sel][order]))
    return float(np.max(branches[1] - branches[0]) / (x.max() - x.min()))


SHAPES = {
    "default": NO_CREEP,
    "gamma0_tanh": {"bw_gamma": 0.0, **NO_CREEP},
    "beta_eq_gamma": {"bw_beta": 0.8, "bw_gamma": 0.8, **NO_CREEP},
    "gamma_negative": {"bw_alpha": 0.2, "bw_beta": 1.0, "bw_gamma": -0.5, **NO_CREEP},
}


@pytest.mark.parametrize("name", SHAPES)
def test_loop_width_matches_the_closed_form_at_any_speed(name):
    """(H6) vs the simulated periodic loop at 3001 and 30011 samples per period (two drive
    speeds, turning points off the samples): within 2e-4 relative; its turning-point
    hysteresis Z within 1e-5 relative; |h| <= d z_s (H4)."""
    over = SHAPES[name]
    p = ph.piezo_values(over)
    expected = ph.loop_width(p, U_TOP)
    z_peak = ph.loop_peak_z(p, U_TOP)
    assert 0.0 < expected < 0.5
    for per_period in (3001, 30011):
        u, x, h = periodic_loop(over, U_TOP, per_period)
        assert measured_width(u, x) == pytest.approx(expected, rel=2e-4)
        assert np.max(h) / GAIN == pytest.approx(z_peak, rel=1e-5)
        assert np.max(np.abs(h)) <= GAIN * ph.saturation_z(p)


def test_default_loop_is_a_typical_piezo_stack_loop():
    """10-15 % of the stroke at the stage's top drive; the loop closes up as the drive falls
    and, the hysteresis being bounded (H4), becomes a small part of a large stroke:
    width <= z_s / (U - z_s)."""
    p = ph.piezo_values()
    assert 0.10 <= ph.loop_width(p, U_TOP) <= 0.15
    assert ph.loop_width(p, 0.1) < ph.loop_width(p, 0.5) < ph.loop_width(p, U_TOP)
    zs = ph.saturation_z(p)
    for amp in (5.0, 20.0):
        assert ph.loop_width(p, amp) <= zs / (amp - zs) * (1.0 + 1e-12)


def test_gamma_zero_peak_is_the_tanh_closed_form():
    """Z = (alpha/beta) tanh(beta U) for gamma = 0, against the root of (H5)."""
    for a, b, amp in ((0.3, 1.0, 1.3), (0.1, 4.0, 0.2), (0.45, 0.5, 3.0)):
        p = ph.piezo_values({"bw_alpha": a, "bw_beta": b, "bw_gamma": 0.0})
        assert ph.loop_peak_z(p, amp) == pytest.approx(a / b * math.tanh(b * amp), rel=1e-13)


@pytest.mark.parametrize("overrides", [NO_CREEP, N2], ids=["n1_exact", "n2_rk4"])
def test_hysteresis_is_rate_independent(overrides):
    """The same path (a random triangle wave, vertices on samples) at two speeds, 10x apart:
    h at the vertices equal within 1e-12 (n = 1, exact) or 1e-8 (n = 2, RK4) of the loop
    width; the same samples at another sample rate give the same h bit for bit."""
    rng = np.random.default_rng(20260)
    vertices = np.concatenate([[0.0], rng.uniform(-1.5, 1.5, 40)])
    width = loop_scale(ph.piezo_values(NO_CREEP))
    h_vertex = []
    for per_ramp in (30, 300):
        s = np.arange(1, per_ramp + 1) / per_ramp
        u = np.concatenate([a + (b - a) * s for a, b in zip(vertices[:-1], vertices[1:])])
        h = ph.PiezoActuator(overrides, gain=GAIN).step(u).h
        h_vertex.append(h[per_ramp - 1 :: per_ramp])
    tol = 1e-12 if ph.piezo_values(overrides)["bw_n"] == 1.0 else 1e-8
    assert np.max(np.abs(h_vertex[0] - h_vertex[1])) <= tol * GAIN * width
    u = 1.2 * np.sin(np.linspace(0.0, 30.0, 5000)) ** 3
    slow = ph.PiezoActuator(overrides, gain=GAIN, sample_rate_hz=1e3).step(u).h
    fast = ph.PiezoActuator(overrides, gain=GAIN, sample_rate_hz=1e7).step(u).h
    assert np.array_equal(bits(slow), bits(fast))


# ------------------------------------------------------------------- 3. creep
@pytest.mark.parametrize("hysteresis", [False, True], ids=["creep_only", "with_hysteresis"])
def test_creep_after_a_step_follows_its_laws(hysteresis):
    """Step 0 -> 1.3 V at 1 kHz over 1000 s: y / x0 matches the bank's closed form (C2)
    within 1e-9, the log law (C3) within 0.02 kappa over tau_1 <= t <= tau_N / 30, and
    creeps kappa per decade there (within 0.04 kappa)."""
    over = {} if hysteresis else HYST_OFF
    p = ph.piezo_values(over)
    fs = 1000.0
    u = np.full(1_000_000, U_TOP)
    fr = ph.PiezoActuator(over, gain=GAIN, sample_rate_hz=fs).step(u)
    x0 = GAIN * U_TOP - fr.h[0]  # the hysteretic step (H1), creep-free at t = 0
    assert np.all(fr.h == fr.h[0])
    t = np.arange(u.size) / fs
    ratio = fr.x / x0
    assert np.max(np.abs(ratio - ph.creep_step_response(p, t))) < 1e-9
    taus = ph.creep_taus(p)
    window = (t >= taus[0]) & (t <= taus[-1] / 30.0)
    kappa = p["creep_per_decade"]
    log_err = np.max(np.abs(ratio[window] - ph.creep_log_law(p, t[window]))) / kappa
    assert log_err < 0.02
    k = np.flatnonzero(window & (10.0 * t <= taus[-1] / 30.0))
    per_decade = (ratio[10 * k] - ratio[k]) / kappa
    assert np.max(np.abs(per_decade - 1.0)) < 0.04
    assert ratio[-1] == pytest.approx(1.0 + kappa * (len(taus) - 1 + -math.expm1(-10.0)))


def test_creep_log_time_is_the_bank_mean_offset():
    """t_e of (C3): the decade bank's mean offset 1/2 + euler_gamma / ln 10 decades below
    tau_1, against a fine numerical average of (C2) over one inner decade."""
    p = ph.piezo_values({"creep_decades": 10})
    t = p["creep_tau_min_s"] * np.logspace(3.0, 4.0, 20001)[:-1]
    offset = (ph.creep_step_response(p, t) - 1.0) / p["creep_per_decade"] - np.log10(t)
    t_e = 10.0 ** -np.mean(offset)
    assert t_e == pytest.approx(ph.creep_log_time(p), rel=1e-6)


# ------------------------------------------------------------------- 4. ideal and blocks
def test_ideal_setting_is_the_linear_piezo_bit_for_bit():
    """:data:`IDEAL` gives x = d u exactly (signed zeros too), for n = 1 and n = 2, and
    h = 0."""
    rng = np.random.default_rng(7)
    u = np.concatenate([rng.normal(0.0, 2.0, 5000), [0.0, -0.0, 1e-300, -1e300, 5.0]])
    for extra in ({}, {"bw_n": 3.0, "creep_decades": 0}):
        act = ph.PiezoActuator({**ph.IDEAL, **extra}, gain=GAIN, sample_rate_hz=FS)
        fr = act.step(u)
        assert np.array_equal(bits(fr.x), bits(GAIN * u))
        assert np.all(fr.h == 0.0)


@pytest.mark.parametrize("overrides", [{}, N2], ids=["default", "n2_rk4"])
def test_block_streaming_equals_one_call_bit_for_bit(overrides):
    """The same drive in random blocks (empty ones included) gives the bits of one call,
    and the same carried state."""
    rng = np.random.default_rng(11)
    u = np.cumsum(rng.normal(0.0, 0.05, 20_000))
    one = ph.PiezoActuator(overrides, gain=GAIN, sample_rate_hz=FS)
    ref = one.step(u)
    cuts = np.sort(np.concatenate([rng.integers(0, u.size, 40), [0, 0, 500, 500]]))
    blk = ph.PiezoActuator(overrides, gain=GAIN, sample_rate_hz=FS)
    parts = [blk.step(u[a:b]) for a, b in zip([0, *cuts], [*cuts, u.size])]
    assert np.array_equal(bits(np.concatenate([q.x for q in parts])), bits(ref.x))
    assert np.array_equal(bits(np.concatenate([q.h for q in parts])), bits(ref.h))
    assert np.array_equal(bits(blk.state), bits(one.state))


# ------------------------------------------------------------------- 5. validation
@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"bw_alpha": 1.5}, "'bw_alpha' = 1.5 is out of range"),
        ({"bw_alpha": -0.1}, "'bw_alpha' = -0.1 is out of range"),
        ({"bw_beta": -1.0}, "'bw_beta' = -1.0 is out of range"),
        ({"bw_gamma": 1.5}, "must be >= |bw_gamma|"),
        ({"bw_beta": 0.0, "bw_gamma": 0.0}, "needs bw_beta \\+ bw_gamma > 0"),
        ({"bw_alpha": 0.9, "bw_gamma": 0.0}, "moves against the drive"),
        ({"bw_n": 0.5}, "'bw_n' = 0.5 is out of range"),
        ({"bw_substeps": 0}, "'bw_substeps' = 0 is out of range"),
        ({"bw_substeps": 2.5}, "expected an integer"),
        ({"creep_per_decade": -0.01}, "'creep_per_decade' = -0.01 is out of range"),
        ({"creep_per_decade": float("nan")}, "must be finite"),
        ({"creep_tau_min_s": 0.0}, "'creep_tau_min_s' = 0.0 is out of range"),
        ({"creep_decades": 13}, "'creep_decades' = 13 is out of range"),
        ({"bw_delta": 1.0}, "unknown parameter 'bw_delta'"),
    ],
)
def test_out_of_range_parameters_raise(overrides, message):
    with pytest.raises(ParameterError, match=message):
        ph.PiezoActuator(overrides)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"gain": 0.0}, "gain = 0.0 is out of range"),
        ({"gain": -GAIN}, "gain = .* is out of range"),
        ({"gain": float("nan")}, "gain = nan is out of range"),
        ({"sample_rate_hz": math.inf}, "sample_rate_hz = inf is out of range"),
        ({"sample_rate_hz": "fast"}, "expected a number"),
        ({"u0": math.nan}, "u0 = nan is invalid"),
    ],
)
def test_out_of_range_arguments_raise(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        ph.PiezoActuator({}, **kwargs)


def test_closed_forms_refuse_what_they_do_not_cover():
    with pytest.raises(ParameterError, match="needs bw_n = 1"):
        ph.loop_width(ph.piezo_values(N2), 1.0)
    with pytest.raises(ParameterError, match="needs bw_n = 1 and bw_alpha > 0"):
        ph.loop_peak_z(ph.piezo_values(ph.IDEAL), 1.0)
    with pytest.raises(ValueError, match="finite"):
        ph.PiezoActuator().step(np.array([0.0, np.inf]))
