"""Consistency statistics of the resonator's Kalman observer over many seeds (Colinet et al.).

What Kalman theory promises, and what is tested here (Anderson & Moore 1979, Ch. 4-5;
Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4):

* the normalised innovations nu(k)/sqrt(S) are white with unit variance (NIS = 1),
  tested with one Ljung-Box portmanteau test pooled over all seeds (Ljung & Box 1978);
* the a-posteriori state error e(k) = X(k) - X(k|k) has the covariance the filter states
  (NEES = 1 per degree of freedom), and it is *not* white: its autocorrelation is the one
  the filter predicts, ((I - K C) A)^m P+ without the noise cross term
  (:func:`mems_sim.kernels.resonator_observer.predicted_error_acf`, Anderson & Moore 1979).

These hold exactly only in the linear-Gaussian case: the device's ``quantizer: gaussian``
stand-in replaces the one-bit quantiser by the additive white Gaussian noise of the
observer's model (Colinet et al. eq. 13) in the same loop.  With the real one-bit
quantiser the quantisation error is neither white nor independent of the signal, so the
innovations are only approximately white; the NEES and the error autocorrelation are
still expected close to the filter's figures while the modulator is in range.

A run here is the ROS-free device core (:class:`mems_sim.devices.resonator.SdResonatorDevice`,
in-loop steady-state observer timing the pulses) plus the same steady-state observer run
offline on its output for the whole a-posteriori state; the statistics are about the filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.special import ndtr

from mems_sim.devices.resonator import SdResonatorDevice, default_pulse_amplitude
from mems_sim.kernels.resonator_models import modulate
from mems_sim.kernels.resonator_observer import KalmanObserver, predicted_error_acf

__all__ = [
    "FS",
    "F0",
    "Q",
    "lag_products",
    "pooled_acf",
    "ljung_box_pooled",
    "overload_fraction",
    "replay_comparator_input",
    "OVERLOAD_LIMIT",
    "SeedRun",
    "analyse_stream",
    "run_seed",
    "Pooled",
    "pool",
]

FS, F0, Q = 1.0e6, 5.0e4, 100.0


def lag_products(x: np.ndarray, lags: int) -> np.ndarray:
    """Sums of lagged products sum_t x(t) x(t+m), m = 0..lags (FFT, exact to rounding).

    Args:
        x: (n,) series (the caller removes its mean if wanted). lags: largest lag.
    Returns:
        (lags + 1,) sums; element 0 is sum x^2.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    X = np.fft.rfft(x, nfft)
    r = np.fft.irfft(X * np.conj(X), nfft)[: lags + 1]
    return r


def pooled_acf(segments: list[np.ndarray], lags: int) -> tuple[np.ndarray, np.ndarray]:
    """Autocorrelation pooled over independent segments (seeds), lags 1..lags.

    r(m) = sum_s sum_t x_s(t) x_s(t+m) / sum_s sum_t x_s(t)^2, each segment's mean removed
    (products never span two segments).

    Returns:
        (r (lags,), pair counts N_m (lags,) = sum_s (n_s - m)).
    """
    num = np.zeros(lags + 1)
    counts = np.zeros(lags)
    for x in segments:
        x = np.asarray(x, dtype=float)
        num += lag_products(x - x.mean(), lags)
        counts += x.size - np.arange(1, lags + 1)
    return num[1:] / num[0], counts


def ljung_box_pooled(segments: list[np.ndarray], lags: int = 50) -> tuple[float, float, np.ndarray]:
    """One Ljung-Box test of whiteness pooled over independent segments (Ljung & Box 1978).

    Ljung & Box 1978: Q = n (n + 2) sum_{m=1..h} r(m)^2 / (n - m) ~ chi^2(h) for a white
    series of length n, (n - m)/(n (n + 2)) being the finite-sample variance of r(m).
    Pooled over segments of total length N, r(m) is :func:`pooled_acf` and n - m becomes
    the number of lag-m pairs N_m, so Q = N (N + 2) sum r(m)^2 / N_m (one segment: the
    original statistic).  No parameters are fitted, so the degrees of freedom are h.

    Returns:
        (Q, p-value, r (h,)).
    """
    r, counts = pooled_acf(segments, lags)
    n = float(sum(np.asarray(x).size for x in segments))
    q = n * (n + 2.0) * float(np.sum(r**2 / counts))
    return q, float(stats.chi2.sf(q, lags)), r


def overload_fraction(position: np.ndarray, output_noise_std: float, ref: float = 1.0) -> float:
    """Expected fraction of samples at which the modulator input y + b exceeds its reference.

    mean_k P(|y(k) + b| > ref), b ~ N(0, sigma_b^2), from the true position y(k): the
    one-bit second-order modulator (Colinet et al. eqs. 10-12) is driven beyond its +-1 V
    DAC levels there, and no additive linear model of its quantiser holds.
    """
    y = np.asarray(position, dtype=float)
    if output_noise_std <= 0:
        return float(np.mean(np.abs(y) > ref))
    s = float(output_noise_std)
    return float(np.mean(ndtr((-ref - y) / s) + ndtr((y - ref) / s)))


#: Fraction of samples with the one-bit quantiser overloaded (|q| > 2 V, so that the
#: quantisation error exceeds Delta/2 = 1 V and the additive model of Colinet et al. eqs.
#: 11-12 no longer bounds it) above which a run is reported as modulator overload rather
#: than judged against the linear model's figures.  Stated assumption, from the measured
#: boundary: 0.03 % / 1.0 % / 2.2 % at 0.25 V + 0.25 V / 0.5 V + 0.25 V / 0.25 V + 0.5 V
#: (NEES 0.96-1.10), 6.5-7.7 % at 0.4 V + 0.5 V / 0.5 V + 0.4 V (NEES up to 1.3 / 2.2),
#: 17 % at 0.5 V + 0.5 V (NEES 1.8-3.3).
OVERLOAD_LIMIT = 0.05


def replay_comparator_input(
    seed: int, position: np.ndarray, bits: np.ndarray, output_noise_std: float
) -> np.ndarray | None:
    """Comparator input q(k) of the device's modulator, replayed from its seed.

    The output noise b of :class:`mems_sim.devices.resonator.SdResonatorDevice` is the first
    child stream of ``SeedSequence(seed)`` drawn from sample 0; the modulator
    (:func:`mems_sim.kernels.resonator_models.modulate`, eqs. 10-12) is re-run on y + b.
    The replay is accepted only if it reproduces the device's bits exactly.

    Returns:
        (n,) q, V, or None if the replayed bits differ (another noise layout).
    """
    y = np.asarray(position, dtype=float)
    gen = np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(seed)).spawn(2)[0]))
    b = gen.standard_normal(y.size) * output_noise_std if output_noise_std > 0 else 0.0
    v, q = modulate(y + b)
    return q if np.array_equal(v, np.asarray(bits)) else None


@dataclass
class SeedRun:
    """Statistics of one seed (after the start-up ``skip``)."""

    seed: int
    nees: float  # NEES per degree of freedom over the resonator states (position, velocity/w0)
    nees_position: float  # position error variance / predicted
    nis: float  # mean squared normalised innovation
    err_std: float  # position error std, V
    amplitude: float  # sqrt(2) std of the true position, V
    corr_err_est: float  # corr(position error, position estimate)
    corr_err_x: float  # corr(position error, true position)
    overload: float  # expected fraction of modulator-input samples beyond +-1 V
    q_std: float = math.nan  # comparator-input std (one-bit runs), V
    q_overload: float = math.nan  # fraction of samples with |q| > 2 V (quantiser overloaded)
    wrong_err_std: float = math.nan  # position error std with a wrong f0 model, V
    wrong_corr_x: float = math.nan  # corr(that error, true position)
    err: np.ndarray = field(default=None, repr=False)  # position error series
    innov: np.ndarray = field(default=None, repr=False)  # normalised innovations


def analyse_stream(
    bits: np.ndarray,
    pulses: np.ndarray,
    starts: np.ndarray,
    widths: np.ndarray,
    position: np.ndarray,
    velocity: np.ndarray,
    output_noise_std: float,
    state_noise_std: float,
    *,
    linear_output: bool = False,
    skip: int = 50_000,
    f0_error: float | None = None,
    seed: int | None = None,
    f0: float = F0,
    q: float = Q,
) -> SeedRun:
    """Run the exact-model steady-state observer on one recorded stream; its statistics.

    Args:
        bits: (n,) modulator output (+-1, or real-valued with ``linear_output``).
        pulses, starts, widths: the drive (V, s, s).  position (V), velocity (V/s): truth.
        output_noise_std, state_noise_std: the model's b and f, V.
        linear_output: the stream comes from the ``quantizer: gaussian`` stand-in.
        skip: start-up samples excluded.  f0_error: if given, also run an observer with this
            relative f0 error.  seed: the device's run seed (one-bit streams: the comparator
            input is replayed from it, :func:`replay_comparator_input`).
        f0, q: the observer model's resonance [Hz] and quality factor [-] (default: the
            nominal Colinet Sec. 6 values; a scenario passes its identified model).
    """
    io = (bits, pulses, starts, widths)
    f0_model, q_model = f0, q

    def observer(f0_hz: float) -> KalmanObserver:
        """The steady-state observer of the model at resonance f0_hz [Hz], initial
        covariance 0."""
        return KalmanObserver(
            f0_hz,
            q_model,
            FS,
            output_noise_std,
            state_noise_std,
            steady_state=True,
            linear_output=linear_output,
            initial_cov=np.zeros((6, 6)),
        )

    ko = observer(f0_model)
    xf = ko.step_states(*io)[skip:]
    innov = ko.last_innovations[skip:]
    x = np.asarray(position, dtype=float)[skip:]
    xv = np.asarray(velocity, dtype=float)[skip:] / ko.model.w0
    e = np.column_stack([x - xf[:, 0], xv - xf[:, 1]])
    pp = ko.ss["P_post"][:2, :2]
    nees = float(np.mean(np.einsum("ki,ij,kj->k", e, np.linalg.inv(pp), e))) / 2.0
    err = e[:, 0]
    out = SeedRun(
        seed=-1 if seed is None else int(seed),
        nees=nees,
        nees_position=float(np.mean(err**2) / pp[0, 0]),
        nis=float(np.mean(innov**2)),
        err_std=float(err.std()),
        amplitude=math.sqrt(2.0) * float(x.std()),
        corr_err_est=float(np.corrcoef(err, xf[:, 0])[0, 1]),
        corr_err_x=float(np.corrcoef(err, x)[0, 1]),
        overload=overload_fraction(x, output_noise_std),
        err=err,
        innov=innov,
    )
    if not linear_output and seed is not None:
        q = replay_comparator_input(seed, position, bits, output_noise_std)
        if q is not None:
            out.q_std = float(q[skip:].std())
            out.q_overload = float(np.mean(np.abs(q[skip:]) > 2.0))
    if f0_error is not None:
        wrong = observer(f0_model * (1.0 + f0_error))
        pw, _ = wrong.step(*io)
        ew = pw[skip:] - x
        out.wrong_err_std = float(ew.std())
        out.wrong_corr_x = float(np.corrcoef(ew, x)[0, 1])
    return out


def run_seed(
    seed: int,
    amplitude: float = 0.25,
    output_noise_std: float = 0.25,
    state_noise_std: float = 5e-4,
    quantizer: str = "one_bit",
    n: int = 1_000_000,
    skip: int = 50_000,
    f0_error: float | None = None,
) -> SeedRun:
    """One seed of the ROS-free device core (observer loop, in-loop exact steady-state
    observer timing the pulses), analysed by :func:`analyse_stream`.

    Args:
        seed: run seed. amplitude: target oscillation amplitude, V (sets the pulse height).
        output_noise_std, state_noise_std: b and f of the device and of the model, V.
        quantizer: "one_bit" or "gaussian" (the linear-Gaussian stand-in).
        n: samples. skip: start-up samples excluded.
        f0_error: if given, also run an observer with this relative f0 error on the stream.
    """
    dev = SdResonatorDevice(
        dict(
            output_noise_std=output_noise_std,
            state_noise_std=state_noise_std,
            observer_state_noise_std=state_noise_std,
            pulse_amplitude=default_pulse_amplitude(amplitude),
            quantizer=quantizer,
            fast=True,
        ),
        seed=seed,
    )
    fr = dev.step(n)
    return analyse_stream(
        fr.bits,
        fr.pulses,
        fr.pulse_start,
        fr.pulse_width,
        fr.position,
        fr.velocity,
        output_noise_std,
        state_noise_std,
        linear_output=quantizer == "gaussian",
        skip=skip,
        f0_error=f0_error,
        seed=seed,
    )


@dataclass
class Pooled:
    """Statistics pooled over seeds."""

    seeds: list[int]
    ljung_box_q: float  # innovations, lags 1..lb_lags
    ljung_box_p: float
    innov_acf: np.ndarray  # pooled innovation autocorrelation, lags 1..lb_lags
    err_acf: np.ndarray  # pooled position-error autocorrelation, lags 1..acf_lags
    predicted_acf: np.ndarray  # the filter's predicted one, lags 1..acf_lags
    acf_max_dev: float  # max |err_acf - predicted_acf|
    acf_max_dev_lag: int

    @property
    def innov_acf1(self) -> float:
        return float(self.innov_acf[0])


def pool(
    runs: list[SeedRun],
    output_noise_std: float = 0.25,
    state_noise_std: float = 5e-4,
    lb_lags: int = 50,
    acf_lags: int = 2000,
) -> Pooled:
    """Pool seeds: one Ljung-Box test on the innovations, the error autocorrelation against
    the filter's prediction (:func:`predicted_error_acf`)."""
    q, p, r_inn = ljung_box_pooled([r.innov for r in runs], lb_lags)
    r_err, _ = pooled_acf([r.err for r in runs], acf_lags)
    model = KalmanObserver(F0, Q, FS, output_noise_std, state_noise_std).model
    pred = predicted_error_acf(model, acf_lags)
    dev = np.abs(r_err - pred)
    i = int(np.argmax(dev))
    return Pooled(
        seeds=[r.seed for r in runs],
        ljung_box_q=q,
        ljung_box_p=p,
        innov_acf=r_inn,
        err_acf=r_err,
        predicted_acf=pred,
        acf_max_dev=float(dev[i]),
        acf_max_dev_lag=i + 1,
    )
