"""IMU multi-position, rate-table and thermal calibration (ROS-free core).

Measurement model (per sensor s = gyro, accel; body frame, SI; a = output axis)::

    y_s = D_s(T) C_s u_s + b_s + b_T,s (T - T_ref)  (+ G f   for the gyro)
    C_s = I + diag(sf) + M                          (3x3, row = output axis, column = input axis)
    D_s(T) = diag(1 + sf_T,s (T - T_ref))           (the gain of output axis a drifts)

with u_gyro = w the true angular rate [rad/s], u_accel = f the true specific force [m/s^2],
T the device temperature [degC], T_ref = :data:`T_REF_C` = 25 degC, b the bias at T_ref,
b_T the bias temperature coefficient [unit/K], sf_T the scale-factor temperature
coefficient [1/K] (per output axis; the emulator's convention) and G the gyro's
g-sensitivity [(rad/s)/(m/s^2)]. Parameter names (the emulator's ``truth_calibration``
and mems_msgs/CalibrationResult): ``{s}_bias_{a}``,
``{s}_matrix_{a}{b}`` (element (a, b) of C), ``{s}_bias_tempco_{a}``, ``{s}_sf_tempco_{a}``,
``gyro_g_sensitivity_{a}{b}``.

Method (the multi-position and rate-table calibration of Titterton & Weston, "Strapdown
Inertial Navigation Technology", 2nd ed., IEE 2004, Sec. 8.3-8.4, in the least-squares form of
Syed, Aggarwal, Goodall, Niu & El-Sheimy, "A new multi-position calibration method for MEMS
inertial navigation systems", Meas. Sci. Technol. 18 (2007) 1897-1907):

1. Segment means. Each profile segment (a position, optionally turning on the rate table, with
   a known temperature ramp) is averaged after dropping its first ``settle_s``: measured means
   ybar_i (per channel) and the means of the known regressors over the same samples (true
   rate wbar_i and specific force fbar_i from the profile, dTbar_i = mean(T - T_ref),
   mean(w_a dT), mean(f_a dT)). Data whose segment means do not follow the profile's (a
   static record, another profile, a late start) are refused (CalibrationError, by
   :func:`~mems_estimation.identification.imu_profile_check.profile_mismatch`): the fit
   would succeed on them and be confidently wrong.
2. Per output axis a, one linear model of the segment means,
   ``ybar_a,i = b_a + sum_b C_ab ubar_b,i + b_T,a dTbar_i + D_aa mean(u_a dT)_i
   (+ sum_b G_ab fbar_b,i)`` with D_aa = C_aa sf_T,a (the off-diagonal products sf_T,a C_ab,
   a != b, are of second order -- 1e-3 x 1e-4/K -- and left out of the fit). Accelerometer:
   gravity +g up_body of every segment, static and turning. Gyro: the table rate
   (rate-table segments) and zero (static segments); the earth's rate is ignored (the
   emulator's truth has none; on a real bench it biases the gyro bias and g-sensitivity by
   up to 7.3e-5 rad/s = 15 deg/h times the cosine of the axis to the earth's axis).
   A regressor a profile does not excite (all zero) or that is a linear combination of
   regressors kept before it (order: bias, diagonal, off-diagonal, bias tempco, sf tempco,
   g-sensitivity) is dropped: its parameter is *unobservable* in this profile and keeps its
   ``base`` value (given calibration, else the model's neutral value 0, or 1 on C's
   diagonal), subtracted from the data first. A dropped regressor that is not zero is
   *aliased*: its effect lands on a kept parameter (e.g. thermal_ramp: z is always up, so the
   accelerometer's z bias tempco carries b_T,z + g C_zz sf_T,z); both names are listed in
   :attr:`ImuCalibration.aliases`.
3. Generalised least squares with the covariance Sigma of the segment means of the noise
   (:func:`segment_mean_covariance`: white, Gauss-Markov bias instability, random walk,
   quantisation, including the correlation *between* segments, which dominates at 60 s
   segments with T ~ 100 s): beta = (X' S^-1 X)^-1 X' S^-1 y, cov = (X' S^-1 X)^-1, times
   the Birge ratio chi2/dof when that exceeds 1 (a model too optimistic for the data widens
   the intervals, never narrows them). 95 % intervals: beta +- 1.96 se. sf_T,a =
   D_aa / C_aa with the delta method. The noise model (N, B, T, K per channel) is given
   (``identify_noise`` on a static record, a datasheet) or, with ``noise=None``, estimated
   from the data (:func:`estimate_noise`: pooled overlapping Allan variance inside the
   segments, Gauss-Markov correlation time fixed, see there).

:func:`correct` inverts the model; :mod:`~mems_estimation.identification.imu_calibration_io`
stores a calibration (YAML) and reads noise models.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mems_estimation.identification.imu_profile_check import profile_mismatch

__all__ = [
    "T_REF_C",
    "SENSORS",
    "AXES",
    "UNITS",
    "NoiseSpec",
    "SegmentStats",
    "ImuCalibration",
    "CalibrationError",
    "parameter_names",
    "parameter_unit",
    "nominal_noise",
    "noise_from_params",
    "segment_statistics",
    "segment_mean_covariance",
    "estimate_noise",
    "calibrate",
    "calibrate_profile",
    "correct",
]

#: Reference temperature of biases and scale factors [degC].
T_REF_C = 25.0
SENSORS = ("gyro", "accel")
AXES = "xyz"
UNITS = {"gyro": "rad/s", "accel": "m/s^2"}
#: Two-sided 95 % normal quantile.
Z95 = 1.959963984540054
#: Relative column norm below which a regressor counts as not excited / dependent.
_RANK_TOL = 1e-6


class CalibrationError(ValueError):
    """Data that cannot be calibrated (too short, no usable segment, bad shapes)."""


def parameter_names(sensor: str) -> list[str]:
    """All parameter names of ``sensor`` (module docstring), in a fixed order."""
    out = [f"{sensor}_bias_{a}" for a in AXES]
    out += [f"{sensor}_matrix_{a}{b}" for a in AXES for b in AXES]
    out += [f"{sensor}_bias_tempco_{a}" for a in AXES]
    out += [f"{sensor}_sf_tempco_{a}" for a in AXES]
    if sensor == "gyro":
        out += [f"gyro_g_sensitivity_{a}{b}" for a in AXES for b in AXES]
    return out


ALL_NAMES = parameter_names("gyro") + parameter_names("accel")


def parameter_unit(name: str) -> str:
    """SI unit of a parameter name."""
    if name.startswith("gyro_g_sensitivity"):
        return "(rad/s)/(m/s^2)"
    sensor = name.split("_")[0]
    if "_matrix_" in name:
        return "1"
    if "_sf_tempco_" in name:
        return "1/K"
    if "_bias_tempco_" in name:
        return f"{UNITS[sensor]}/K"
    return UNITS[sensor]


def _neutral(name: str) -> float:
    """Value of a parameter in the ideal sensor (1 on C's diagonal, else 0)."""
    if "_matrix_" in name and name[-1] == name[-2]:
        return 1.0
    return 0.0


# ------------------------------------------------------------------------------ noise model


@dataclass(frozen=True)
class NoiseSpec:
    """Noise of one sensor's three channels (per axis arrays, SI).

    N white density [u*sqrt(s)] (= u/sqrt(Hz)); B Gauss-Markov bias instability (stationary
    std) [u]; T its correlation time [s]; K random-walk coefficient [u/sqrt(s)]; lsb ADC
    resolution [u] (quantisation as white noise of variance lsb^2/12 per sample).
    """

    N: np.ndarray
    B: np.ndarray
    T: np.ndarray
    K: np.ndarray
    lsb: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @staticmethod
    def of(N, B, T, K, lsb=0.0) -> NoiseSpec:
        """Per-axis arrays from scalars or 3-sequences."""
        b = [np.broadcast_to(np.asarray(v, float), (3,)).copy() for v in (N, B, T, K, lsb)]
        return NoiseSpec(*b)


def noise_from_params(values: Mapping[str, Any]) -> dict[str, NoiseSpec]:
    """Noise of both sensors from emulator parameter names (``gyro_noise_density``,
    ``gyro_bias_instability``, ``gyro_correlation_time``, ``gyro_random_walk``, ``gyro_lsb``,
    same for ``accel_``); missing names take the ADIS16350 defaults of
    :mod:`mems_sim.devices.imu`."""
    from mems_sim.devices.imu import IMU_SPECS

    d = {s.name: s.default for s in IMU_SPECS}
    d.update(values)
    return {
        s: NoiseSpec.of(
            d[f"{s}_noise_density"],
            d[f"{s}_bias_instability"],
            d[f"{s}_correlation_time"],
            d[f"{s}_random_walk"],
            d[f"{s}_lsb"],
        )
        for s in SENSORS
    }


def nominal_noise(preset: str = "petkov") -> dict[str, NoiseSpec]:
    """The noise of an emulator preset of :mod:`mems_sim.devices.imu` ("petkov" and
    "adis16350": Petkov & Slavov's ADIS16350 terms; "icm42688p")."""
    from mems_sim.devices.imu import imu_values

    return noise_from_params(imu_values({"preset": preset}))


def _h_gm(u: np.ndarray, T: float) -> np.ndarray:
    """H(u) = T^2 e^{-|u|/T} + T|u|, H'' = e^{-|u|/T} (double integral of the GM kernel)."""
    au = np.abs(u)
    return T * T * np.exp(-au / T) + T * au


def segment_mean_covariance(
    t0: np.ndarray,
    t1: np.ndarray,
    counts: np.ndarray,
    N: float,
    B: float,
    T: float,
    K: float,
    lsb: float = 0.0,
) -> np.ndarray:
    """Covariance [u^2] of the means of one channel's noise over intervals [t0_i, t1_i) [s]
    (times from the record's first sample, where the random walk starts at 0).

    * white (density N [u sqrt(s)]) and quantisation (lsb [u]): N^2/L_i + lsb^2/(12 n_i) on
      the diagonal (n_i = counts, L_i = t1_i - t0_i);
    * Gauss-Markov (stationary std B [u], correlation time T [s], kernel B^2 e^{-|t-s|/T}):
      B^2/(L_i L_j) [H(t1_j - t0_i) - H(t1_j - t1_i) - H(t0_j - t0_i) + H(t0_j - t1_i)]
      with H(u) = T^2 e^{-|u|/T} + T|u|;
    * random walk (K [u/sqrt(s)], kernel K^2 min(t, s)): K^2 (t0_i + L_i/3) on the
      diagonal, K^2 (t0_i + t1_i)/2 for segment i before j (disjoint).
    """
    t0, t1 = np.asarray(t0, float), np.asarray(t1, float)
    L = t1 - t0
    cnt = np.asarray(counts, float)
    S = np.diag(N * N / L + lsb * lsb / 12.0 / cnt)
    if B > 0:
        a0, a1 = t0[:, None], t1[:, None]
        b0, b1 = t0[None, :], t1[None, :]
        H = _h_gm(b1 - a0, T) - _h_gm(b1 - a1, T) - _h_gm(b0 - a0, T) + _h_gm(b0 - a1, T)
        S += B * B * H / (L[:, None] * L[None, :])
    if K > 0:
        mid = 0.5 * (t0 + t1)
        i, j = np.meshgrid(np.arange(t0.size), np.arange(t0.size), indexing="ij")
        first = np.where(t0[i] <= t0[j], i, j)
        R = mid[first]
        R[np.diag_indices(t0.size)] = t0 + L / 3.0
        S += K * K * R
    return S


# ------------------------------------------------------------------------------ segments


@dataclass
class SegmentStats:
    """Per-segment means (module docstring, step 1); arrays over the m segments used.

    Attributes:
        segment: profile segment numbers; start, stop: sample offsets [first, stop) into the
        data; t0, t1 [s] from the first sample; count samples;
        y: (m, 6) measured means gyro_x..z [rad/s], accel_x..z [m/s^2];
        w, f: (m, 3) true rate [rad/s] / specific force [m/s^2] means;
        dT: (m,) mean T - T_ref [K]; w_dT, f_dT: (m, 3) means of w*dT, f*dT;
        fs: sample rate [Hz].
    """

    segment: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    t0: np.ndarray
    t1: np.ndarray
    count: np.ndarray
    y: np.ndarray
    w: np.ndarray
    f: np.ndarray
    dT: np.ndarray
    w_dT: np.ndarray
    f_dT: np.ndarray
    fs: float


def _check_data(gyro, accel, temperature=None):
    g = np.asarray(gyro, float)
    a = np.asarray(accel, float)
    if g.ndim != 2 or g.shape[1] != 3 or a.shape != g.shape:
        raise CalibrationError(
            f"gyro and accel must both be (n, 3) arrays: got {g.shape} and {a.shape}"
        )
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(a))):
        raise CalibrationError("gyro or accel holds non-finite values")
    if temperature is not None:
        t = np.asarray(temperature, float)
        if t.shape != (g.shape[0],) or not np.all(np.isfinite(t)):
            raise CalibrationError(f"temperature must be {g.shape[0]} finite values [degC]")
    return g, a


def segment_statistics(
    gyro: np.ndarray,
    accel: np.ndarray,
    truth,
    fs: float,
    settle_s: float = 1.0,
    temperature: np.ndarray | None = None,
    min_seconds: float = 5.0,
    index: np.ndarray | None = None,
) -> SegmentStats:
    """Segment means (module docstring, step 1).

    Args:
        gyro, accel: (n, 3) measured rate [rad/s] and specific force [m/s^2], consecutive
            samples of the profile.
        truth: the profile's truth of the same samples (a
            :class:`mems_sim.devices.imu_profiles.ProfileTruth`: gyro, accel, temperature_c,
            segment; segment -1 after the profile's end).
        fs: sample rate [Hz]; settle_s: leading seconds of each segment dropped [s].
        temperature: (n,) measured device temperature [degC] (e.g. the IMU's temperature
            sensor); None: the profile's.
        min_seconds: a segment with less data after settling is not used [s].
        index: (n,) increasing sample indices of the rows (a record with gaps: the rows
            present); None: consecutive. Times t0, t1 and the counts follow the indices.
    """
    g, a = _check_data(gyro, accel, temperature)
    seg = np.asarray(truth.segment)
    n = g.shape[0]
    if seg.shape != (n,):
        raise CalibrationError(f"profile truth has {seg.shape} segment numbers for {n} samples")
    temp = np.asarray(truth.temperature_c if temperature is None else temperature, float)
    dT = temp - T_REF_C
    tw, tf = np.asarray(truth.gyro, float), np.asarray(truth.accel, float)
    idx = np.arange(n) if index is None else np.asarray(index, np.int64)
    if idx.shape != (n,) or (n > 1 and np.any(np.diff(idx) <= 0)):
        raise CalibrationError("sample indices must be n increasing integers")
    change = np.flatnonzero(np.diff(seg)) + 1
    bounds = np.concatenate([[0], change, [n]])
    skip = int(round(settle_s * fs))
    rows = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        s = int(seg[lo])
        if s < 0:
            continue
        # drop the samples within settle_s of the segment's first sample present
        lo2 = lo + int(np.searchsorted(idx[lo:hi], idx[lo] + skip))
        if hi - lo2 < max(2, int(min_seconds * fs)):
            continue
        sl = slice(lo2, hi)
        rows.append(
            (
                s,
                lo2,
                hi,
                np.concatenate([g[sl].mean(0), a[sl].mean(0)]),
                tw[sl].mean(0),
                tf[sl].mean(0),
                dT[sl].mean(),
                (tw[sl] * dT[sl, None]).mean(0),
                (tf[sl] * dT[sl, None]).mean(0),
            )
        )
    if not rows:
        raise CalibrationError(
            f"no profile segment with at least {min_seconds:g} s of data after settling"
        )
    col = list(zip(*rows))
    start = np.array(col[1], np.int64)
    stop = np.array(col[2], np.int64)
    return SegmentStats(
        segment=np.array(col[0], np.int64),
        start=start,
        stop=stop,
        t0=(idx[start] - idx[0]) / fs,
        t1=(idx[stop - 1] + 1 - idx[0]) / fs,
        count=stop - start,
        y=np.array(col[3]),
        w=np.array(col[4]),
        f=np.array(col[5]),
        dT=np.array(col[6]),
        w_dT=np.array(col[7]),
        f_dT=np.array(col[8]),
        fs=float(fs),
    )


def estimate_noise(
    gyro: np.ndarray,
    accel: np.ndarray,
    stats: SegmentStats,
    correlation_time_s: float | None = None,
    lsb: Sequence[float] | None = None,
) -> dict[str, NoiseSpec]:
    """Noise model estimated from the data inside the segments (``noise=None``).

    Per channel the overlapping Hadamard-free Allan variance of each segment's samples at
    tau = 2^k / fs (k = 0.., tau <= L_min / 4) is pooled over segments (sums of squared
    second differences of the phase over their counts), and N^2, B^2, K^2 are fitted to it
    by non-negative weighted least squares with the Gauss-Markov correlation time fixed to
    ``correlation_time_s`` (default: the segment length; segments of 60 s cannot separate B
    and T of a process with T ~ 100 s, and the fit only has to reproduce the variance at
    tau up to the segment length). A linear drift inside a segment (a temperature ramp)
    adds slope^2 tau^2 / 2 and is mostly taken as random walk (conservative).
    """
    from scipy.optimize import nnls

    from mems_estimation.identification.imu_noise_fit import avar_gm

    g, a = _check_data(gyro, accel)
    data = np.hstack([g, a])
    fs = stats.fs
    L = int(stats.count.min())
    ms = 2 ** np.arange(0, max(1, int(math.log2(max(L // 4, 1))) + 1))
    ms = ms[ms <= max(L // 4, 1)]
    num = np.zeros((ms.size, 6))
    den = np.zeros(ms.size)
    for lo, hi in zip(stats.start, stats.stop):
        x = data[lo:hi] - data[lo:hi].mean(0)
        ph = np.vstack([np.zeros((1, 6)), np.cumsum(x, 0)]) / fs
        for k, m in enumerate(ms):
            if ph.shape[0] <= 2 * m:
                continue
            d2 = ph[2 * m :] - 2 * ph[m:-m] + ph[: -2 * m]
            num[k] += np.sum(d2 * d2, 0)
            den[k] += d2.shape[0]
    taus = ms / fs
    ok = den > 0
    avar = num[ok] / (2.0 * taus[ok, None] ** 2 * den[ok, None])
    taus = taus[ok]
    T = float(correlation_time_s or L / fs)
    basis = np.column_stack([1.0 / taus, avar_gm(taus, 1.0, T), taus / 3.0])
    out = {}
    lsb = np.zeros(6) if lsb is None else np.asarray(lsb, float)
    for si, s in enumerate(SENSORS):
        pars = np.zeros((3, 3))
        for k in range(3):
            c = 3 * si + k
            w = 1.0 / avar[:, c]
            A = basis * w[:, None]
            sc = np.linalg.norm(A, axis=0)
            sol, _ = nnls(A / sc, avar[:, c] * w)
            pars[k] = np.sqrt(sol / sc)
        out[s] = NoiseSpec.of(pars[:, 0], pars[:, 1], T, pars[:, 2], lsb[3 * si : 3 * si + 3])
    return out


# ------------------------------------------------------------------------------ result


@dataclass
class ImuCalibration:
    """A calibration: parameter values and standard errors by name (SI, module docstring).

    Attributes:
        values, standard_errors: name -> value / s.e. (NaN: not estimated); every name of
            :data:`ALL_NAMES` is present in ``values`` (unestimated ones at their base or
            neutral value).
        estimated: names estimated from data (the others are base or neutral values).
        aliases: estimated name -> text naming the parameters it also carries: those the
            profile cannot separate from it and that ``base`` did not give (e.g.
            thermal_ramp: accel_bias_tempco_z also carries accel_sf_tempco_z, as
            b_T,z + g C_zz sf_T,z); such a value is not the parameter alone.
        t_ref_c: reference temperature [degC]; method; info: counts, residuals, noise source.
    """

    values: dict[str, float]
    standard_errors: dict[str, float]
    estimated: list[str]
    aliases: dict[str, str] = field(default_factory=dict)
    t_ref_c: float = T_REF_C
    method: str = "multi_position_gls"
    info: dict[str, Any] = field(default_factory=dict)

    def ci95(self, name: str) -> tuple[float, float]:
        """95 % interval of ``name`` (NaN where not estimated)."""
        v, se = self.values[name], self.standard_errors.get(name, math.nan)
        return v - Z95 * se, v + Z95 * se

    def matrix(self, sensor: str) -> np.ndarray:
        """C of ``sensor`` (3x3, row = output axis)."""
        return np.array([[self.values[f"{sensor}_matrix_{a}{b}"] for b in AXES] for a in AXES])

    def vector(self, sensor: str, what: str) -> np.ndarray:
        """``bias``, ``bias_tempco`` or ``sf_tempco`` of ``sensor`` (3,)."""
        return np.array([self.values[f"{sensor}_{what}_{a}"] for a in AXES])

    def g_sensitivity(self) -> np.ndarray:
        """G (3x3) [(rad/s)/(m/s^2)]."""
        return np.array([[self.values[f"gyro_g_sensitivity_{a}{b}"] for b in AXES] for a in AXES])

    def table(self, names: Sequence[str] | None = None) -> list[tuple[str, float, str, float]]:
        """Rows (name, value, unit, 95 % half width) of the estimated parameters."""
        names = self.estimated if names is None else names
        return [
            (n, self.values[n], parameter_unit(n), Z95 * self.standard_errors.get(n, math.nan))
            for n in names
        ]


def neutral_calibration() -> ImuCalibration:
    """The ideal sensor (C = I, everything else 0), nothing estimated."""
    return ImuCalibration(
        {n: _neutral(n) for n in ALL_NAMES}, {n: math.nan for n in ALL_NAMES}, [], method="none"
    )


# ------------------------------------------------------------------------------ fit


def _columns(sensor: str, a: int, st: SegmentStats, thermal: bool):
    """Candidate (name, regressor) of output axis a in priority order (module doc, step 2)."""
    u = st.w if sensor == "gyro" else st.f
    u_dT = st.w_dT if sensor == "gyro" else st.f_dT
    ax = AXES[a]
    cols = [(f"{sensor}_bias_{ax}", np.ones(u.shape[0]))]
    cols.append((f"{sensor}_matrix_{ax}{ax}", u[:, a]))
    cols += [(f"{sensor}_matrix_{ax}{AXES[b]}", u[:, b]) for b in range(3) if b != a]
    if thermal:
        cols.append((f"{sensor}_bias_tempco_{ax}", st.dT))
        cols.append((f"{sensor}_D_{ax}{ax}", u_dT[:, a]))
    if sensor == "gyro":
        cols += [(f"gyro_g_sensitivity_{ax}{AXES[b]}", st.f[:, b]) for b in range(3)]
    return cols


def _select(cols, scale_rows):
    """Keep columns in order unless zero or dependent on those kept (scaled rank test)."""
    kept, dropped_zero, dropped_dep = [], [], []
    basis = np.zeros((scale_rows, 0))
    for name, x in cols:
        nx = np.linalg.norm(x)
        if nx <= _RANK_TOL * math.sqrt(x.size):
            dropped_zero.append(name)
            continue
        xn = x / nx
        if basis.shape[1]:
            q, _ = np.linalg.qr(basis)
            r = xn - q @ (q.T @ xn)
            if np.linalg.norm(r) < 1e-6:
                dropped_dep.append(name)
                continue
        basis = np.column_stack([basis, xn])
        kept.append(name)
    return kept, dropped_zero, dropped_dep


def _gls(X: np.ndarray, y: np.ndarray, S: np.ndarray):
    """GLS estimate, covariance (Birge-inflated, module doc step 3), chi2 and dof."""
    Lc = np.linalg.cholesky(S)
    Xw = np.linalg.solve(Lc, X)
    yw = np.linalg.solve(Lc, y)
    beta, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
    r = yw - Xw @ beta
    chi2 = float(r @ r)
    dof = X.shape[0] - X.shape[1]
    cov = np.linalg.inv(Xw.T @ Xw)
    birge = chi2 / dof if dof > 0 else 1.0
    return beta, cov * max(1.0, birge), chi2, dof, r


def _param_name(sensor, kind, a, b=None):
    return f"{sensor}_{kind}_{AXES[a]}" + ("" if b is None else AXES[b])


def calibrate(
    gyro: np.ndarray,
    accel: np.ndarray,
    truth,
    fs: float,
    settle_s: float = 1.0,
    temperature: np.ndarray | None = None,
    noise: Mapping[str, NoiseSpec] | None = None,
    thermal: bool | None = None,
    base: ImuCalibration | None = None,
    min_seconds: float = 5.0,
    index: np.ndarray | None = None,
) -> ImuCalibration:
    """Calibrate both sensors from data along a profile (module docstring).

    Args:
        gyro, accel: (n, 3) measured [rad/s], [m/s^2] (e.g. ADC codes x LSB).
        truth: the profile's truth of the same n samples
            (:func:`mems_sim.devices.imu_profiles.profile_truth`).
        fs: sample rate [Hz]; settle_s: dropped head of each segment [s].
        temperature: (n,) measured device temperature [degC]; None: the profile's.
        noise: ``{"gyro": NoiseSpec, "accel": NoiseSpec}`` (N, B, T, K per axis, SI); None:
            :func:`estimate_noise` from the data.
        thermal: fit the temperature terms (b_T, sf_T); None: if the segment temperatures
            span more than 1 K.
        base: values of the parameters this profile cannot observe (e.g. the matrix from a
            multi-position calibration under a thermal ramp); None: neutral values.
        min_seconds: least data per segment after settling [s].
        index: (n,) sample indices of the rows when samples are missing (gaps).
    Returns:
        :class:`ImuCalibration` with values, standard errors and the lists of estimated and
        aliased parameters.
    """
    st = segment_statistics(gyro, accel, truth, fs, settle_s, temperature, min_seconds, index)
    mismatch = profile_mismatch(st)
    if mismatch is not None:
        raise CalibrationError(mismatch)
    if thermal is None:
        thermal = bool(np.ptp(st.dT) > 1.0) if st.dT.size else False
    noise_source = "given"
    if noise is None:
        noise = estimate_noise(gyro, accel, st)
        noise_source = "estimated from the data (estimate_noise)"
    base = base or neutral_calibration()
    values = dict(base.values)
    ses = {n: base.standard_errors.get(n, math.nan) for n in ALL_NAMES}
    estimated: list[str] = []
    aliases: dict[str, str] = {}
    info: dict[str, Any] = {
        "segments": int(st.segment.size),
        "samples": int(st.count.sum()),
        "thermal": bool(thermal),
        "noise": noise_source,
        "temperature_range_c": [float(st.dT.min() + T_REF_C), float(st.dT.max() + T_REF_C)],
        "rows": {},
    }
    # the products sf_T,a C_ab (a != b) left out of the linear fit: subtracted with the
    # previous pass's values (passes converge by a factor ~ sf_T dT ~ 1e-2 each)
    cross = np.zeros_like(st.y)
    values0 = dict(values)
    for _pass in range(3 if thermal else 1):
        values = dict(values0)
        estimated, aliases = [], {}
        d_fit: dict[str, tuple[float, float, float, float]] = {}  # D_aa: value, var, cov w/ C_aa
        for si, sensor in enumerate(SENSORS):
            spec = noise[sensor]
            for a in range(3):
                ax = AXES[a]
                cols = _columns(sensor, a, st, thermal)
                kept, zero, dep = _select(cols, st.segment.size)
                y = st.y[:, 3 * si + a] - cross[:, 3 * si + a]
                # parameters not fitted: their base value's contribution is known
                cdict = dict(cols)
                for name in zero + dep:
                    if name.endswith(f"_D_{ax}{ax}"):
                        base_v = (
                            values[f"{sensor}_matrix_{ax}{ax}"] * values[f"{sensor}_sf_tempco_{ax}"]
                        )
                    else:
                        base_v = values[name]
                    y -= base_v * cdict[name]
                if not kept or y.size < len(kept):
                    raise CalibrationError(
                        f"{sensor} {ax}: {y.size} segments for {len(kept)} parameters"
                    )
                for name in dep:
                    pub = _public(name, sensor, ax)
                    if pub in base.estimated:
                        continue  # its base value was subtracted: the kept ones are clean
                    for k in kept:
                        if _dependent_on(cdict, k, name, kept):
                            kp = _public(k, sensor, ax)
                            aliases[kp] = (
                                aliases[kp] + ", " if kp in aliases else "also carries "
                            ) + pub
                X = np.column_stack([cdict[k] for k in kept])
                S = segment_mean_covariance(
                    st.t0, st.t1, st.count, spec.N[a], spec.B[a], spec.T[a], spec.K[a], spec.lsb[a]
                )
                beta, cov, chi2, dof, _ = _gls(X, y, S)
                info["rows"][f"{sensor}_{ax}"] = {
                    "parameters": len(kept),
                    "segments": int(y.size),
                    "chi2": chi2,
                    "dof": int(dof),
                }
                for k, name in enumerate(kept):
                    if name.startswith(f"{sensor}_D_"):
                        ic = (
                            kept.index(f"{sensor}_matrix_{ax}{ax}")
                            if (f"{sensor}_matrix_{ax}{ax}" in kept)
                            else None
                        )
                        d_fit[f"{sensor}_{ax}"] = (
                            float(beta[k]),
                            float(cov[k, k]),
                            float(cov[k, ic]) if ic is not None else 0.0,
                            float(cov[ic, ic]) if ic is not None else 0.0,
                        )
                        continue
                    values[name] = float(beta[k])
                    ses[name] = float(math.sqrt(cov[k, k]))
                    estimated.append(name)
        # sf tempco = D_aa / C_aa (delta method)
        for key, (dv, dvar, dc, cvar) in d_fit.items():
            sensor, ax = key.split("_")
            c = values[f"{sensor}_matrix_{ax}{ax}"]
            name = f"{sensor}_sf_tempco_{ax}"
            s = dv / c
            var = (dvar - 2 * s * dc + s * s * cvar) / (c * c)
            values[name] = float(s)
            ses[name] = float(math.sqrt(max(var, 0.0)))
            estimated.append(name)
        for si, sensor in enumerate(SENSORS):
            u_dT = st.w_dT if sensor == "gyro" else st.f_dT
            for a in range(3):
                sf = values[f"{sensor}_sf_tempco_{AXES[a]}"]
                cross[:, 3 * si + a] = sf * sum(
                    values[f"{sensor}_matrix_{AXES[a]}{AXES[b]}"] * u_dT[:, b]
                    for b in range(3)
                    if b != a
                )
    order = {n: i for i, n in enumerate(ALL_NAMES)}
    estimated.sort(key=order.__getitem__)
    return ImuCalibration(
        values,
        ses,
        estimated,
        {k: v for k, v in aliases.items() if k in order},
        method="multi_position_gls" + ("_thermal" if thermal else ""),
        info=info,
    )


def _public(name: str, sensor: str, ax: str) -> str:
    """Internal D_aa -> the sf tempco it carries."""
    return f"{sensor}_sf_tempco_{ax}" if name.startswith(f"{sensor}_D_") else name


def _dependent_on(cdict, k, name, kept) -> bool:
    """Whether kept column k takes part in the linear combination that gives column name."""
    X = np.column_stack([cdict[c] for c in kept])
    coef, *_ = np.linalg.lstsq(X, cdict[name], rcond=None)
    return abs(coef[kept.index(k)]) > 1e-9 * (np.abs(coef).max() or 1.0)


def calibrate_profile(
    gyro: np.ndarray,
    accel: np.ndarray,
    profile,
    fs: float,
    index: np.ndarray | None = None,
    temperature: np.ndarray | None = None,
    device_temperature_c: float = T_REF_C,
    **kwargs,
) -> ImuCalibration:
    """:func:`calibrate` along a :class:`mems_sim.devices.imu_profiles.ImuProfile` (its
    truth and settle time), the profile starting at the first row.

    Args:
        gyro, accel: (n, 3) measured [rad/s], [m/s^2].
        profile: the profile; fs: sample rate [Hz].
        index: (n,) increasing stream sample indices of the rows (gaps allowed); profile
            sample k is stream index index[0] + k. None: consecutive rows.
        temperature: (n,) measured temperature [degC] or None (the profile's).
        device_temperature_c: temperature of segments without their own [degC].
        kwargs: of :func:`calibrate` (noise, thermal, base, min_seconds, settle_s).
    """
    from mems_sim.devices.imu_profiles import ProfileTruth, profile_truth

    n = np.asarray(gyro).shape[0]
    if n == 0:
        raise CalibrationError("no samples")
    if index is None:
        rel = np.arange(n, dtype=np.int64)
    else:
        rel = np.asarray(index, np.int64) - int(index[0])
    full = profile_truth(profile, 0, int(rel[-1]) + 1, fs, device_temperature_c)
    truth = ProfileTruth(*(x[rel] for x in full))
    kwargs.setdefault("settle_s", profile.settle_s)
    cal = calibrate(gyro, accel, truth, fs, temperature=temperature, index=rel, **kwargs)
    cal.info["profile"] = profile.name
    covered = int(np.count_nonzero(truth.segment >= 0))
    cal.info["profile_samples"] = profile.n_samples(fs)
    cal.info["samples_in_profile"] = covered
    return cal


# ------------------------------------------------------------------------------ correction


def correct(
    gyro: np.ndarray, accel: np.ndarray, temperature, calib: ImuCalibration
) -> tuple[np.ndarray, np.ndarray]:
    """Invert the measurement model (module docstring).

    Args:
        gyro, accel: (n, 3) measured [rad/s], [m/s^2].
        temperature: (n,) or scalar device temperature [degC].
        calib: the calibration.
    Returns:
        (rate [rad/s], specific force [m/s^2]), each (n, 3):
        f = C_a^-1 [(y_a - b_a - b_T,a dT) / (1 + sf_T,a dT)], then
        w = C_g^-1 [(y_g - b_g - b_T,g dT - G f) / (1 + sf_T,g dT)], dT = T - T_ref.
    """
    g = np.atleast_2d(np.asarray(gyro, float))
    a = np.atleast_2d(np.asarray(accel, float))
    dT = np.broadcast_to(np.asarray(temperature, float) - calib.t_ref_c, (g.shape[0],))[:, None]
    out = {}
    for s, y in (("accel", a), ("gyro", g)):
        z = y - calib.vector(s, "bias") - calib.vector(s, "bias_tempco") * dT
        if s == "gyro":
            z = z - out["accel"] @ calib.g_sensitivity().T
        z = z / (1.0 + calib.vector(s, "sf_tempco") * dT)
        out[s] = np.linalg.solve(calib.matrix(s), z.T).T
    return out["gyro"], out["accel"]
