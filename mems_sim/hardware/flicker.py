"""Flicker (1/f) noise of a real part: a sum of first-order Gauss-Markov processes.

A superposition of Lorentzian spectra whose relaxation times are spread uniformly in
log(tau) is a 1/f spectrum between the slowest and the fastest of them (van der Ziel, "On
the noise spectra of semi-conductor noise and of flicker effect", Physica 16, 1950;
Keshner, "1/f noise", Proc. IEEE 70(3), 1982: the geometric ladder of time
constants). Here K first-order Gauss-Markov (AR(1)) processes x_k, exactly
discretised at the sample interval dt = 1/fs, have time constants spaced geometrically
from tau_min = 1/(2 pi f_high) to tau_max = 1/(2 pi f_low), at least ``poles_per_decade``
of them per decade (ratio r between neighbours), and are summed in a fixed order.

Target: the bias-instability term of IEEE Std 952-1997, Annex C: the two-sided
rate PSD (B^2 / 2 pi) / f, i.e. the one-sided PSD

    S(f) = B^2 / (pi f)                                                   (1)

whose Allan variance is the flat floor sigma^2 = (2 ln 2 / pi) B^2, i.e. sigma_Allan =
B sqrt(2 ln 2 / pi) = 0.664 B (Annex C, bias instability). A continuous-time Gauss-Markov process of
variance s^2 and time constant tau has the one-sided Lorentzian 4 s^2 tau / (1 + (2 pi f
tau)^2); summed over tau_k = tau_min r^k with equal variances s^2 the sum approximates
(1 / ln r) int 4 s^2 tau / (1 + (2 pi f tau)^2) dtau / tau = s^2 / (f ln r), which is (1)
for

    s_k^2 = B^2 ln r / pi.                                                (2)

The truncation of the ladder at tau_max removes (4 s^2 / ln r) / ((2 pi f)^2 tau_max
sqrt(r)) from the integral at f >> f_low (the poles beyond tau_max sqrt(r)); a single pole at
tau_max carries that much when its variance grows by s^2 / (sqrt(r) ln r), so the slowest
pole gets

    s_K^2 = s^2 (1 + 1 / (sqrt(r) ln r))                                  (3)

(derived here; it moves the low end of the 1/f band from about 20 f_low to 2 f_low). The
fast end is not corrected: there the sampled processes' aliased tails already lift the
PSD above (1) towards the Nyquist frequency.

The sampled process is exact (no discretisation error): x_k[n] = a_k x_k[n-1] + b_k w_k[n]
with a_k = exp(-dt / tau_k), b_k = s_k sqrt(1 - a_k^2), w_k white N(0, 1) (Brown & Hwang,
"Introduction to Random Signals and Applied Kalman Filtering", first-order Gauss-Markov
process), started from its stationary distribution. Its one-sided PSD and Allan variance
(:func:`flicker_psd`, :func:`flicker_avar`) are closed forms of the discrete processes,
so a simulated record can be compared with them to its statistical error alone.

Portable results: the recursion is ``scipy.signal.lfilter`` of order one (a sequential
loop), the coefficients come from scalar ``math`` functions and the K processes are
added elementwise in the order k = 0 .. K-1; no reduction whose order a library chooses.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize, signal

from mems_sim.params import ParameterError, ParamSpec, Spread, resolve

__all__ = [
    "FLOOR_FACTOR",
    "DEFAULT_RIPPLE",
    "FlickerConfig",
    "flicker_specs",
    "flicker_config",
    "pole_time_constants",
    "pole_variances",
    "ar1_coefficients",
    "initial_state",
    "flicker_block",
    "flicker_noise",
    "ideal_psd",
    "flicker_floor",
    "flicker_psd",
    "flicker_avar",
    "flicker_adev",
    "flicker_band",
    "flat_allan_range",
]

#: sigma_Allan / B of pure flicker, sqrt(2 ln 2 / pi) = 0.6643 (IEEE Std 952-1997, Annex C).
FLOOR_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: Relative tolerance, -, within which :func:`flicker_band` calls the PSD 1/f and
#: :func:`flat_allan_range` calls the Allan deviation flat (two poles per decade ripple
#: +-0.2 % inside the band, one pole per decade +-5 %).
DEFAULT_RIPPLE = 0.02
#: Frequency grid density of the band search, points per decade.
_GRID_PER_DECADE = 100

_F_MIN, _F_MAX = 1.0e-7, 5.0e4  # Hz, corner frequency range
_SOURCE_BAND = (
    "assumption: MEMS gyro and accelerometer Allan plots show the bias-instability floor "
    "between about 1 s and 1e3 s (IEEE Std 952-1997, Annex C, bias instability); the 1/f band "
    "reaches from about 2 f_low to f_high / 20 at fs = 2 f_high"
)


# ----------------------------------------------------------------------------- parameters
def flicker_specs(
    prefix: str = "flicker",
    unit: str = "rad/s",
    coefficient: float = 0.0,
    coefficient_max: float = 1.0,
    coefficient_source: str = "IEEE Std 952-1997, Annex C: bias instability B; "
    "0 switches the term off",
    f_low_hz: float = 1.0e-4,
    f_high_hz: float = 1.0,
    poles_per_decade: int = 2,
    spread: Spread | None = None,
) -> tuple[ParamSpec, ...]:
    """Parameter table of one flicker term, its signal unit the caller's choice.

    Args:
        prefix: name prefix, e.g. ``"gyro_flicker"`` -> ``gyro_flicker_coefficient``.
        unit: unit of the signal and of B, e.g. ``"rad/s"`` or ``"m/s^2"``.
        coefficient: default flicker coefficient B, ``unit``.
        coefficient_max: largest allowed B, ``unit``.
        coefficient_source: where the default B comes from (datasheet, paper).
        f_low_hz: default lower corner f_low = 1/(2 pi tau_max), Hz.
        f_high_hz: default upper corner f_high = 1/(2 pi tau_min), Hz.
        poles_per_decade: default least number of Gauss-Markov processes per decade, -.
        spread: manufacturing spread of B, if any.
    """
    return (
        ParamSpec(
            f"{prefix}_coefficient",
            float(coefficient),
            unit,
            "flicker coefficient B: one-sided PSD B^2/(pi f), Allan floor 0.664 B",
            coefficient_source,
            min=0.0,
            max=float(coefficient_max),
            spread=spread,
        ),
        ParamSpec(
            f"{prefix}_f_low_hz",
            float(f_low_hz),
            "Hz",
            "lower corner of the 1/f band, 1/(2 pi tau_max) of the slowest process",
            _SOURCE_BAND,
            min=_F_MIN,
            max=_F_MAX,
        ),
        ParamSpec(
            f"{prefix}_f_high_hz",
            float(f_high_hz),
            "Hz",
            "upper corner of the 1/f band, 1/(2 pi tau_min) of the fastest process (at most fs/2)",
            _SOURCE_BAND,
            min=_F_MIN,
            max=_F_MAX,
        ),
        ParamSpec(
            f"{prefix}_poles_per_decade",
            int(poles_per_decade),
            "-",
            "least number of Gauss-Markov processes per decade of the band",
            "Keshner, Proc. IEEE 70(3) 1982: geometric ladder; assumption: two per decade "
            "(ripple +-0.2 % inside the band, one per decade +-5 %)",
            min=1,
            max=8,
        ),
    )


@dataclass(frozen=True)
class FlickerConfig:
    """One flicker term.

    Attributes:
        coefficient: flicker coefficient B, signal unit (rad/s, m/s^2, ...).
        f_low_hz: lower corner f_low = 1/(2 pi tau_max), Hz.
        f_high_hz: upper corner f_high = 1/(2 pi tau_min), Hz (at least 10 f_low).
        poles_per_decade: least number of processes per decade, -.
    """

    coefficient: float
    f_low_hz: float = 1.0e-4
    f_high_hz: float = 1.0
    poles_per_decade: int = 2

    def __post_init__(self) -> None:
        specs = flicker_specs(coefficient_max=math.inf)
        for spec, value in zip(specs, self._values(), strict=True):
            spec.validate(value)
        _check_corners(self.f_low_hz, self.f_high_hz, "flicker")

    def _values(self) -> tuple[Any, ...]:
        return (self.coefficient, self.f_low_hz, self.f_high_hz, self.poles_per_decade)

    @property
    def n_poles(self) -> int:
        """Number K of Gauss-Markov processes, ceil(p log10(f_high/f_low)) + 1, -."""
        decades = math.log10(self.f_high_hz / self.f_low_hz)
        return math.ceil(self.poles_per_decade * decades - 1e-9) + 1

    @property
    def ratio(self) -> float:
        """Ratio r = tau_{k+1} / tau_k of neighbouring time constants, -."""
        return (self.f_high_hz / self.f_low_hz) ** (1.0 / (self.n_poles - 1))


def _check_corners(f_low_hz: float, f_high_hz: float, prefix: str) -> None:
    """Raise ParameterError unless f_high >= 10 f_low (a band of at least a decade)."""
    if not f_high_hz >= 10.0 * f_low_hz:
        raise ParameterError(
            f"parameters '{prefix}_f_low_hz' = {f_low_hz!r} Hz and '{prefix}_f_high_hz' = "
            f"{f_high_hz!r} Hz are invalid: the 1/f band needs f_high >= 10 f_low"
        )


def flicker_config(
    values: Mapping[str, Any] | None = None,
    prefix: str = "flicker",
    specs: tuple[ParamSpec, ...] | None = None,
) -> FlickerConfig:
    """A validated :class:`FlickerConfig` from parameter values.

    Args:
        values: overrides by parameter name (``<prefix>_coefficient`` ...), SI units.
        prefix: the table's name prefix.
        specs: the table (:func:`flicker_specs` with this prefix if None).
    Raises:
        ParameterError: an unknown name, a value out of range, or f_high < 10 f_low.
    """
    specs = flicker_specs(prefix) if specs is None else specs
    v = resolve(specs, values)
    _check_corners(v[f"{prefix}_f_low_hz"], v[f"{prefix}_f_high_hz"], prefix)
    return FlickerConfig(
        coefficient=v[f"{prefix}_coefficient"],
        f_low_hz=v[f"{prefix}_f_low_hz"],
        f_high_hz=v[f"{prefix}_f_high_hz"],
        poles_per_decade=v[f"{prefix}_poles_per_decade"],
    )


def _check_rate(fs: float, config: FlickerConfig) -> float:
    """fs as a float; ParameterError unless 0 < fs < inf and f_high <= fs/2."""
    if isinstance(fs, bool) or not isinstance(fs, (int, float)) or not 0.0 < fs < math.inf:
        raise ParameterError(f"sample rate fs = {fs!r} Hz is invalid: allowed (0, inf) Hz")
    if config.f_high_hz > 0.5 * fs:
        raise ParameterError(
            f"flicker upper corner f_high = {config.f_high_hz!r} Hz is above the Nyquist "
            f"frequency fs/2 = {0.5 * fs!r} Hz"
        )
    return float(fs)


# ----------------------------------------------------------------------------- the ladder
def pole_time_constants(config: FlickerConfig) -> np.ndarray:
    """Time constants tau_k = tau_min r^k, k = 0 .. K-1, s (tau_min = 1/(2 pi f_high),
    tau_{K-1} = 1/(2 pi f_low); Keshner, Proc. IEEE 70(3), 1982)."""
    tau_min = 1.0 / (2.0 * math.pi * config.f_high_hz)
    tau_max = 1.0 / (2.0 * math.pi * config.f_low_hz)
    k_last = config.n_poles - 1
    taus = [tau_min * config.ratio**k for k in range(k_last)] + [tau_max]
    return np.array(taus)


def pole_variances(config: FlickerConfig) -> np.ndarray:
    """Stationary variances s_k^2 of the processes, eqs. (2)-(3) of the module docstring,
    signal unit squared: B^2 ln r / pi each, the slowest (1 + 1/(sqrt(r) ln r)) times that."""
    r = config.ratio
    s2 = config.coefficient**2 * math.log(r) / math.pi
    var = np.full(config.n_poles, s2)
    var[-1] = s2 * (1.0 + 1.0 / (math.sqrt(r) * math.log(r)))
    return var


def ar1_coefficients(fs: float, config: FlickerConfig) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation a_k = exp(-dt/tau_k), b_k = s_k sqrt(1 - a_k^2) of each process
    (Brown & Hwang, first-order Gauss-Markov process), from scalar ``math`` calls.

    Args:
        fs: sample rate, Hz (f_high <= fs/2).
        config: the flicker term.
    Returns:
        (a -, b signal unit), each (K,).
    """
    dt = 1.0 / _check_rate(fs, config)
    taus, var = pole_time_constants(config), pole_variances(config)
    a = [math.exp(-dt / float(t)) for t in taus]
    b = [math.sqrt(float(v) * -math.expm1(-2.0 * dt / float(t))) for t, v in zip(taus, var)]
    return np.array(a), np.array(b)


# ----------------------------------------------------------------------------- generation
def initial_state(config: FlickerConfig, rng: np.random.Generator) -> np.ndarray:
    """Stationary start: x_k[-1] ~ N(0, s_k^2), one standard normal per process, signal
    unit, (K,)."""
    return np.sqrt(pole_variances(config)) * rng.standard_normal(config.n_poles)


def flicker_block(
    n: int,
    fs: float,
    config: FlickerConfig,
    rng: np.random.Generator,
    state: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The next ``n`` samples of the sum of the processes, continuing from ``state``.

    x_k[i] = a_k x_k[i-1] + b_k w_k[i] (``lfilter`` of order one), w_k drawn as n standard
    normals per process in the order k = 0 .. K-1, and y[i] = x_0[i] + x_1[i] + ... added
    elementwise in that order. Consecutive blocks continue the same process (not the same
    draws as one long block).

    Args:
        n: number of samples, -.
        fs: sample rate, Hz.
        config: the flicker term.
        rng: the random stream.
        state: (K,) last value x_k[-1] of every process, signal unit.
    Returns:
        (y (n,) signal unit, new state (K,) signal unit).
    """
    n = int(n)
    if n < 0:
        raise ParameterError(f"number of samples n = {n!r} is invalid: allowed [0, inf)")
    a, b = ar1_coefficients(fs, config)
    state = np.asarray(state, dtype=float)
    if state.shape != a.shape:
        raise ParameterError(f"flicker state of shape {state.shape} is invalid: expected {a.shape}")
    total = np.zeros(n)
    new_state = state.copy()
    for k in range(a.shape[0]):
        w = rng.standard_normal(n)
        x, _ = signal.lfilter([b[k]], [1.0, -a[k]], w, zi=[a[k] * state[k]])
        total = total + x
        if n:
            new_state[k] = x[-1]
    return total, new_state


def flicker_noise(n: int, fs: float, config: FlickerConfig, rng: np.random.Generator) -> np.ndarray:
    """``n`` samples of flicker noise of coefficient B at rate ``fs``, started stationary
    (:func:`initial_state`, then :func:`flicker_block`); identical bits for the same seed.

    Args:
        n: number of samples, -.
        fs: sample rate, Hz (f_high <= fs/2).
        config: the flicker term (B in the signal unit).
        rng: the random stream, e.g. ``np.random.default_rng(seed)``.
    Returns:
        (n,) samples, signal unit.
    """
    _check_rate(fs, config)
    y, _ = flicker_block(n, fs, config, rng, initial_state(config, rng))
    return y


# ----------------------------------------------------------------------------- spectra
def ideal_psd(f, coefficient: float) -> np.ndarray:
    """Target one-sided PSD B^2/(pi f), eq. (1) (IEEE Std 952-1997, Annex C, two-sided
    (B^2/2 pi)/f doubled).

    Args:
        f: frequencies, Hz (> 0).
        coefficient: B, signal unit.
    Returns:
        PSD, signal unit^2/Hz.
    """
    return coefficient**2 / (math.pi * np.asarray(f, dtype=float))


def flicker_floor(coefficient: float) -> float:
    """Allan deviation floor of pure flicker, B sqrt(2 ln 2 / pi) (IEEE Std 952-1997, Annex C),
    signal unit."""
    return FLOOR_FACTOR * coefficient


def flicker_psd(f, fs: float, config: FlickerConfig) -> np.ndarray:
    """One-sided PSD of the generated sequence: the sum of the AR(1) spectra

        S(f) = sum_k 2 s_k^2 (1 - a_k^2) dt / ((1 - a_k)^2 + 4 a_k sin^2(pi f dt))

    (the AR(1) spectrum, Box & Jenkins, "Time Series Analysis"; one-sided, i.e.
    twice the two-sided density), exact for the sampled processes, aliasing included.

    Args:
        f: frequencies, Hz, in [0, fs/2].
        fs: sample rate, Hz.
        config: the flicker term.
    Returns:
        PSD, signal unit^2/Hz, shaped like ``f``.
    """
    dt = 1.0 / _check_rate(fs, config)
    f = np.asarray(f, dtype=float)
    s2 = np.sin(math.pi * f * dt) ** 2
    out = np.zeros_like(f)
    for tau, var in zip(pole_time_constants(config), pole_variances(config)):
        u = -math.expm1(-dt / tau)  # 1 - a
        a = 1.0 - u
        out = out + 2.0 * var * u * (2.0 - u) * dt / (u * u + 4.0 * a * s2)
    return out


def _ar1_avar(m: np.ndarray, lam: float) -> np.ndarray:
    """Allan variance per unit variance of a unit AR(1) sequence, a = exp(-lam), at m samples.

    With R(j) = a^|j| the two adjacent m-sums S0, S1 have E[(S1 - S0)^2] = 2 D(m) - 2 C(m),
    D(m) = m (1 + a)/(1 - a) - 2 a (1 - a^m)/(1 - a)^2 and C(m) = a (1 - a^m)^2/(1 - a)^2,
    so (derived here; the discrete counterpart of IEEE Std 952-1997, Annex C, exponentially
    correlated noise)

        sigma^2(m) / s^2 = [m (1 + a)/(1 - a) - a (3 - 4 a^m + a^2m)/(1 - a)^2] / m^2,

    evaluated with u = 1 - a = -expm1(-lam), e = a^m - 1 = expm1(-m lam) and
    3 - 4 a^m + a^2m = e (e - 2).
    """
    u = -math.expm1(-lam)
    e = np.expm1(-m * lam)
    return (m * (2.0 - u) / u - (1.0 - u) * e * (e - 2.0) / (u * u)) / (m * m)


def _ms(taus, fs: float) -> np.ndarray:
    """Averaging factors m = round(tau fs) >= 1 of averaging times ``taus`` (s)."""
    m = np.round(np.asarray(taus, dtype=float) * fs)
    if np.any(m < 1.0):
        raise ParameterError(f"averaging times below 1/fs = {1.0 / fs!r} s are invalid")
    return m


def flicker_avar(taus, fs: float, config: FlickerConfig) -> np.ndarray:
    """Allan variance of the generated sequence, sum over k of s_k^2 times
    :func:`_ar1_avar` (exact for the sampled processes; the expectation of the overlapping
    estimator for a stationary record).

    Args:
        taus: averaging times tau = m/fs, s (tau fs rounded to the integer m >= 1).
        fs: sample rate, Hz.
        config: the flicker term.
    Returns:
        Allan variance, signal unit^2, shaped like ``taus``.
    """
    dt = 1.0 / _check_rate(fs, config)
    m = _ms(taus, fs)
    out = np.zeros_like(m)
    for tau, var in zip(pole_time_constants(config), pole_variances(config)):
        out = out + var * _ar1_avar(m, dt / tau)
    return out


def flicker_adev(taus, fs: float, config: FlickerConfig) -> np.ndarray:
    """Allan deviation sqrt(:func:`flicker_avar`), signal unit.

    Args:
        taus: averaging times, s (multiples of 1/fs).
        fs: sample rate, Hz.
        config: the flicker term.
    """
    return np.sqrt(flicker_avar(taus, fs, config))


# ----------------------------------------------------------------------------- bands
def _longest_run(ok: np.ndarray) -> tuple[int, int] | None:
    """First and last index of the longest run of True in ``ok`` (None if none)."""
    best, start = None, None
    for i, good in enumerate(np.append(ok, False)):
        if good and start is None:
            start = i
        elif not good and start is not None:
            if best is None or i - 1 - start > best[1] - best[0]:
                best = (start, i - 1)
            start = None
    return best


def _refine(g, lo: float, hi: float) -> float:
    """Root of g(log f) = 0 between log-frequencies ``lo`` and ``hi`` where it changes sign,
    else the end where g <= 0."""
    if g(lo) * g(hi) < 0.0:
        return float(math.exp(optimize.brentq(g, lo, hi, xtol=1e-6)))
    return float(math.exp(lo if g(lo) <= 0.0 else hi))


def flicker_band(
    fs: float, config: FlickerConfig, ripple: float = DEFAULT_RIPPLE
) -> tuple[float, float]:
    """The band where :func:`flicker_psd` is 1/f, eq. (1), within ``ripple``:
    |S(f) / (B^2/(pi f)) - 1| <= ripple, the longest such interval between f_low/10 and
    fs/2 (grid of 100 points per decade, edges refined to 1e-6 in ln f), at least a decade.

    Args:
        fs: sample rate, Hz.
        config: the flicker term (B > 0).
        ripple: relative tolerance, -.
    Returns:
        (f_lo, f_hi), Hz.
    Raises:
        ParameterError: B = 0, or the PSD is within the ripple over no decade (one pole
            per decade and a ripple below 5 %).
    """
    _check_positive(config)
    fs = _check_rate(fs, config)
    lo, hi = math.log(config.f_low_hz / 10.0), math.log(0.5 * fs)
    n = int(math.ceil((hi - lo) / math.log(10.0) * _GRID_PER_DECADE)) + 1
    logf = np.linspace(lo, hi, n)

    def excess(x):
        f = np.exp(x)
        return np.abs(flicker_psd(f, fs, config) / ideal_psd(f, config.coefficient) - 1.0) - ripple

    run = _longest_run(excess(logf) <= 0.0)
    if run is None or run[1] - run[0] < _GRID_PER_DECADE:
        raise ParameterError(
            f"the flicker PSD is within {ripple!r} of 1/f over no decade with "
            f"{config.poles_per_decade} pole(s) per decade: use more poles or a larger ripple"
        )
    i, j = run
    f_lo = _refine(excess, logf[i - 1], logf[i]) if i > 0 else float(np.exp(logf[i]))
    f_hi = _refine(excess, logf[j], logf[j + 1]) if j < n - 1 else float(np.exp(logf[j]))
    return f_lo, f_hi


def flat_allan_range(
    fs: float, config: FlickerConfig, ripple: float = DEFAULT_RIPPLE
) -> tuple[float, float]:
    """Averaging times where :func:`flicker_adev` is flat at B sqrt(2 ln 2 / pi) within
    ``ripple``: |sigma(tau) / (0.664 B) - 1| <= ripple, the longest such run of m = tau fs
    on a grid of every integer up to 100 and 100 per decade above, up to 10 tau_max fs.

    Args:
        fs: sample rate, Hz.
        config: the flicker term (B > 0).
        ripple: relative tolerance, -.
    Returns:
        (tau_lo, tau_hi), s (multiples of 1/fs).
    Raises:
        ParameterError: B = 0, or the Allan deviation is nowhere within the ripple.
    """
    _check_positive(config)
    fs = _check_rate(fs, config)
    m_max = max(200.0, 10.0 * fs / (2.0 * math.pi * config.f_low_hz))
    n = int(math.ceil(math.log10(m_max / 100.0) * _GRID_PER_DECADE)) + 1
    m = np.unique(np.concatenate([np.arange(1.0, 100.0), np.round(np.geomspace(100, m_max, n))]))
    dev = flicker_adev(m / fs, fs, config) / flicker_floor(config.coefficient)
    run = _longest_run(np.abs(dev - 1.0) <= ripple)
    if run is None:
        raise ParameterError(
            f"the flicker Allan deviation is nowhere within {ripple!r} of 0.664 B with "
            f"{config.poles_per_decade} pole(s) per decade"
        )
    return float(m[run[0]] / fs), float(m[run[1]] / fs)


def _check_positive(config: FlickerConfig) -> None:
    """ParameterError if B = 0 (no flicker: no band to speak of)."""
    if not config.coefficient > 0.0:
        raise ParameterError(
            f"flicker coefficient B = {config.coefficient!r} is invalid here: the band of a "
            "switched-off term (B = 0) is undefined, allowed (0, inf)"
        )
