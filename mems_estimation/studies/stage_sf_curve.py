"""Scale-factor curve SF(T) of the on-stage gyro from in-situ calibrations at several
temperatures (Chen 2018 sec. 3.3.1 eqs. 20-27, sec. 3.6.3; the in-situ design of
:mod:`mems_estimation.identification.stage_insitu`).

Per calibration temperature T_i (the stage model identified once at the training
temperature, 22.9 C):

1. the sensor parameters P_s = (D_n, eta) per channel are re-identified at T_i with the
   LDV-like reference (eq. 55, the thesis' procedure at its second temperature), from a
   training amplitude sweep of ``train_trials`` trials;
2. a calibration amplitude sweep with the gyro: the stage model's response at the drive
   frequency is re-measured from the capacitive channels (eqs. 44, 46-47; eq. 34), the EKF
   (eqs. 48-53) runs on the corrected model, and eq. (27) gives SF(T_i) = k_I|S.

Step 1 is :func:`reidentify_point`, step 2 on the cores :func:`calibrate_point` (a node
graph runs the same sweep from :func:`calibration_seeds` with the in-situ EKF and
calibration nodes instead), the bootstrap below :func:`bootstrap_point`, given step 1's
results and the sweep's (either path's).

SF(T) is then fitted by least squares as a polynomial in T - t_ref (default order 1: the
MPU-6500-like gyro's scale factor is linear in T by construction, k_I(T) = k_ref (1 + c_k
(T - T_ref)), so a quadratic term has no physical counterpart and only widens the band at
the ends of the range).

Uncertainty (the 95 % band): a bootstrap (Efron & Tibshirani 1993) that redoes, per
temperature and replicate, (a) the identification of (D_n, eta) on the training trials
resampled with replacement, (b) the fit of every calibration trial's tilt phasor Theta
with those sensor parameters and the pooled response G on the calibration trials
resampled with replacement, and (c) eq. (27) on the same resampled trials' peak-to-peak
pairs. The EKF on the corrected model is model-driven, so its per-trial peak-to-peak rate
scales with |G| (stage_pp,b = stage_pp |G_b| / |G|) and is not rerun per replicate. The
replicate curves are the polynomial fits of the replicate points (the temperatures'
records are independent); the band is the fit +- t_{0.975, B-1} times the replicates'
standard deviation at each T, widened by the Birge ratio sqrt(chi^2 / (n - order - 1))
of the points about the fit when that exceeds 1 (scatter the bootstrap does not see).

What the band does not contain: errors common to every temperature (the LDV-like
reference's delay and the design electrode layout, both from the training temperature).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.stats import t as student_t

from mems_estimation.filters.stage_ekf import StageEkf, StageModel
from mems_estimation.identification.stage_gyro_calibration import (
    T1,
    Plan,
    calibrate,
    identify_stage,
    least_squares_eq27,
    sweep_devices,
)
from mems_estimation.identification.stage_identification import (
    _predicted,
    cancelled,
    crest_trough,
    evaluate,
    identify_sensor,
    trial_fits,
)
from mems_estimation.identification.stage_insitu import (
    insitu_correct,
    phasors_from_harmonics,
    pooled_response,
)
from mems_sim import bounded_yaml
from mems_sim.devices.stage import DriveSchedule, MicroStage, record
from mems_sim.devices.stage_gyro import MemsGyro

__all__ = [
    "DEFAULT_TEMPERATURES",
    "stream_seed",
    "SensorBootstrap",
    "CurvePoint",
    "reidentify_point",
    "calibration_seeds",
    "calibration_devices",
    "bootstrap_point",
    "point_rng",
    "calibrate_point",
    "fit_sf_curve_points",
    "SfCurve",
    "fit_sf_curve",
    "sf_curve",
    "FORMAT",
    "curve_to_dict",
    "curve_from_dict",
    "save_yaml",
    "load_yaml",
    "RANGE_C",
    "TEST_TEMPERATURES",
    "MAX_DEV_TARGET_PPM",
    "COVER_TARGET",
    "evaluate_curve",
    "sf_curve_study",
]

#: Calibration temperatures [C] of the curve (6 points, 5 K apart, over 20-45 C).
DEFAULT_TEMPERATURES = (20.0, 25.0, 30.0, 35.0, 40.0, 45.0)


def stream_seed(seed: int, temperature_c: float, k: int) -> int:
    """Run seed of record ``k`` (0 training sweep, 1 calibration sweep, 2 gyro) at a
    temperature of the curve: distinct for every (seed, 0.01 C, k), and apart from the
    seeds of :mod:`mems_estimation.identification.stage_gyro_calibration` (< 100 seed +
    200)."""
    return 10_000_000 + int(seed) * 100_000 + int(round(temperature_c * 100)) * 10 + int(k)


class SensorBootstrap:
    """The identification of (D_n, eta) per channel (eq. 55: D_n minimises the crest-to-
    trough misfit over the trials, eta the amplitude misfit at that D_n) redone on
    resampled trials without re-evaluating the sensor model: per trial and channel the
    predicted crest-to-trough distance and the amplitude sums are tabulated once on a grid
    of D_n of +-``span`` around the full-data estimate; a resample (trial counts) then
    minimises the weighted sum on the grid, refined by a parabola, and takes eta from the
    cubic-spline interpolated sums. Agrees with
    :func:`mems_estimation.identification.stage_identification.identify_sensor` on the
    full data to ~2e-5 in D_n (4e-5 in eta, in the direction that compensates)."""

    def __init__(
        self, fits, limits: np.ndarray, gaps0: np.ndarray, span: float = 0.08, n: int = 41
    ) -> None:
        self.nt = len(fits)
        self.nch = limits.shape[0]
        self.grid = np.empty((self.nch, n))
        self.lam = np.array([crest_trough(f.y) for f in fits])  # (trials, nch)
        self.lp = np.empty((self.nt, self.nch, n))
        self.num = np.empty((self.nt, self.nch, n))
        self.den = np.empty((self.nt, self.nch, n))
        for c in range(self.nch):
            g = gaps0[c] * np.linspace(1 - span, 1 + span, n)
            self.grid[c] = g
            sgn = None
            for j, dn in enumerate(g):
                for k, f in enumerate(fits):
                    pr = _predicted(f, dn, limits[c])
                    self.num[k, c, j] = float(np.dot(f.y[1:, c], pr[1:]))
                    self.den[k, c, j] = float(np.dot(pr[1:], pr[1:]))
                    if sgn is None:
                        sgn = math.copysign(1.0, self.num[k, c, j])
                    self.lp[k, c, j] = crest_trough(sgn * pr)[0]

    def identify(self, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(D_n [m], eta) per channel for trial multiplicities ``counts`` (trials,)."""
        w = np.asarray(counts, float)
        gaps, etas = np.empty(self.nch), np.empty(self.nch)
        for c in range(self.nch):
            d = (self.lam[:, c, None] - self.lp[:, c, :] + 0.5) % 1.0 - 0.5
            cost = w @ (d * d)
            j = int(np.clip(np.argmin(cost), 1, cost.size - 2))
            a, b, cc = cost[j - 1], cost[j], cost[j + 1]
            den = a - 2 * b + cc
            x = float(np.clip(0.5 * (a - cc) / den if den > 0 else 0.0, -1.0, 1.0))
            g = self.grid[c]
            dn = g[j] + x * (g[1] - g[0])
            num = CubicSpline(g, w @ self.num[:, c, :])(dn)
            de = CubicSpline(g, w @ self.den[:, c, :])(dn)
            gaps[c], etas[c] = dn, float(num / de)
        return gaps, etas


@dataclass
class CurvePoint:
    """One calibration temperature of the curve: SF = k_I|S of eq. (27) [-], its eq. (27)
    standard error, the bootstrap replicates (B,), the gyro's true k_I(T) (for evaluation
    only), the in-situ EKF's omega RMSE [rad/s] and alpha against the truth, and the
    pooled response G [rad/V] and sensor parameters used."""

    temperature_c: float
    scale_factor: float
    scale_factor_se: float
    boot: np.ndarray
    k_true: float
    omega_rmse: float
    alpha: float
    G: complex
    gaps: np.ndarray
    etas: np.ndarray
    pairs: list = field(default_factory=list)

    @property
    def ppm(self) -> float:
        """SF / k_true - 1 [ppm]."""
        return (self.scale_factor / self.k_true - 1.0) * 1e6

    @property
    def boot_sd_ppm(self) -> float:
        """Standard deviation of the bootstrap replicates [ppm of SF]."""
        return float(np.std(self.boot, ddof=1) / self.scale_factor * 1e6)


def _resample(rng: np.random.Generator, n: int, distinct: int = 1) -> np.ndarray:
    """Indices of a resample with replacement of n items with >= ``distinct`` distinct."""
    while True:
        i = rng.integers(0, n, n)
        if np.unique(i).size >= distinct:
            return i


def training_fits(
    stage_params: dict | None, temperature_c: float, plan: Plan, seed: int, ldv_delay_s: float
) -> list:
    """The LDV training amplitude sweep (``plan.train_trials`` x ``plan.train_periods``
    periods) of the stage at ``temperature_c`` [C], recorded with noise ``seed``, reduced to
    its per-trial fits (the inputs of eq. 55's identification of D_n and eta); the LDV's
    delay ``ldv_delay_s`` [s] as identified."""
    tr = record(
        MicroStage(
            dict(stage_params or {}, temperature_c=temperature_c),
            DriveSchedule.amplitude_sweep(n_trials=plan.train_trials, periods=plan.train_periods),
            seed=seed,
        )
    )
    return trial_fits(
        cancelled(tr), tr["ldv"], tr["phase"], tr["segment"], tr["f_drive"], ldv_delay_s
    )


def reidentify_point(
    model: StageModel,
    temperature_c: float,
    seed: int,
    plan: Plan,
    stage_params: dict | None = None,
) -> tuple[StageModel, list]:
    """Step 1 of the module doc at one temperature: the sensor parameters (D_n [m], eta
    [-]) per channel re-identified at ``temperature_c`` [C] with the LDV-like reference
    (eq. 55) from a training amplitude sweep (record :func:`stream_seed` k = 0). Returns
    (the model of the training temperature with those D_n, eta: the model the calibration
    sweep's in-situ EKF starts from, the training trials' fits the bootstrap resamples)."""
    fits = training_fits(
        stage_params,
        temperature_c,
        plan,
        stream_seed(seed, temperature_c, 0),
        model.extra.get("ldv_delay_s", 0.0),
    )
    gaps, etas, _ = identify_sensor(fits, model.limits)
    mT = copy.deepcopy(model)
    mT.gap, mT.eta = gaps, etas
    mT.extra = dict(model.extra, temperature_c=float(temperature_c))
    return mT, fits


def calibration_seeds(temperature_c: float, seed: int) -> tuple[int, int]:
    """Noise seeds (stage, gyro) of the calibration sweep at ``temperature_c`` [C] of the
    run ``seed`` (:func:`stream_seed` k = 1, 2; a node graph that emulates the same sweep
    seeds its stage node's ``seed`` and ``gyro_seed`` with them)."""
    return stream_seed(seed, temperature_c, 1), stream_seed(seed, temperature_c, 2)


def calibration_devices(
    temperature_c: float,
    seed: int,
    plan: Plan,
    stage_params: dict | None = None,
    gyro_params: dict | None = None,
) -> tuple[MicroStage, MemsGyro]:
    """Step 2's devices at ``temperature_c`` [C]: the stage driven by the calibration
    amplitude sweep (``plan.cal_trials`` x ``plan.cal_periods`` periods) and its gyro,
    seeded by :func:`calibration_seeds` (:func:`sweep_devices`)."""
    seeds = calibration_seeds(temperature_c, seed)
    return sweep_devices(temperature_c, seeds, plan, stage_params, gyro_params)


def bootstrap_point(
    model_t: StageModel,
    fits: list,
    harmonics: list,
    G: complex,
    pairs: list,
    n_boot: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """The bootstrap replicates (``n_boot``,) of SF = k_I|S at one temperature (module
    doc), given step 1's results (``model_t`` with the re-identified D_n, eta, the training
    trials' ``fits``: :func:`reidentify_point`) and the calibration sweep's: the per-trial
    ``harmonics`` of the cancelled channels and the pooled response ``G`` [rad/V] of the
    in-situ correction (eqs. 44, 46-47;
    :func:`mems_estimation.identification.stage_insitu.insitu_correct`) and eq. (27)'s
    peak-to-peak ``pairs`` (dicts with ``segment``, ``stage_pp`` [rad/s], ``gyro_pp``
    [rad/s])."""
    segs = [h["segment"] for h in harmonics]
    by_seg = {p["segment"]: p for p in pairs}
    spp = np.array([by_seg[s]["stage_pp"] for s in segs])
    gpp = np.array([by_seg[s]["gyro_pp"] for s in segs])
    sb = SensorBootstrap(fits, model_t.limits, model_t.gap)
    boot = np.empty(n_boot)
    mb = copy.deepcopy(model_t)
    for b in range(n_boot):
        mb.gap, mb.eta = sb.identify(np.bincount(_resample(rng, len(fits)), minlength=len(fits)))
        ph = phasors_from_harmonics(harmonics, mb)
        ic = _resample(rng, len(harmonics), 3)
        Gb = pooled_response([ph[i] for i in ic])
        boot[b] = least_squares_eq27(spp[ic] * abs(Gb) / abs(G), gpp[ic])["scale_factor"]
    return boot


def point_rng(seed: int, temperature_c: float) -> np.random.Generator:
    """The bootstrap's generator at one temperature of the run ``seed``."""
    return np.random.default_rng([int(seed), int(round(temperature_c * 100))])


def calibrate_point(
    model: StageModel,
    temperature_c: float,
    seed: int,
    plan: Plan,
    stage_params: dict | None = None,
    gyro_params: dict | None = None,
    n_boot: int = 100,
    rng: np.random.Generator | None = None,
) -> CurvePoint:
    """Steps 1-2 of the module doc at one temperature on the ROS-free cores, with
    ``n_boot`` bootstrap replicates (module doc). ``model``: the stage model identified at
    the training temperature
    (:func:`mems_estimation.identification.stage_gyro_calibration.identify_stage`).
    Step 1: :func:`reidentify_point`; step 2: the sweep of :func:`calibration_devices`, the
    in-situ correction (eqs. 44-47), the EKF (eqs. 48-53) on the corrected model and eq.
    (27); the bootstrap: :func:`bootstrap_point`."""
    rng = rng or point_rng(seed, temperature_c)
    mT, fits = reidentify_point(model, temperature_c, seed, plan, stage_params)
    stage, gyro = calibration_devices(temperature_c, seed, plan, stage_params, gyro_params)
    rec = record(stage, gyro)
    yc = cancelled(rec)
    mc, rep = insitu_correct(mT, yc, rec["u"], rec["phase"], rec["segment"], rec["f_drive"])
    x, _ = StageEkf(mc).step(yc, rec["u"], corrected=False)
    ev = evaluate(x[:, 1], rec["omega"][:, 0], rec["phase"], rec["segment"])
    cal = calibrate(rec, x[:, 1])
    del rec, yc, x
    boot = bootstrap_point(mT, fits, rep["harmonics"], rep["G"], cal["pairs"], n_boot, rng)
    return CurvePoint(
        float(temperature_c),
        float(cal["scale_factor"]),
        float(cal["scale_factor_se"]),
        boot,
        float(gyro.scale_factor()),
        float(ev["rmse"]),
        float(ev["alpha"]),
        complex(rep["G"]),
        mT.gap,
        mT.eta,
        cal["pairs"],
    )


@dataclass
class SfCurve:
    """SF(T) = sum_k coef[k] (T - t_ref)^k [-] with its 95 % band.

    ``coef`` (order + 1,), ``cov`` their covariance (from the bootstrap, times the Birge
    ratio squared), ``t_quantile`` the band's quantile, ``birge`` the ratio applied (>= 1),
    ``temperatures``/``values``/``boot_sd`` the calibration points, ``valid_range_c``."""

    coef: np.ndarray
    cov: np.ndarray
    t_ref_c: float
    t_quantile: float
    birge: float
    temperatures: np.ndarray
    values: np.ndarray
    boot_sd: np.ndarray
    valid_range_c: tuple[float, float]
    method: str = "stage_insitu_eq27_polyfit"
    level: float = 0.95

    @property
    def order(self) -> int:
        return int(self.coef.size - 1)

    def _basis(self, temperature_c) -> np.ndarray:
        dt = np.asarray(temperature_c, float)[..., None] - self.t_ref_c
        return dt ** np.arange(self.order + 1)

    def __call__(self, temperature_c):
        """SF at temperature(s) [C]."""
        return self._basis(temperature_c) @ self.coef

    def sd(self, temperature_c):
        """Standard uncertainty of SF(T) (bootstrap x Birge ratio) [-]."""
        X = self._basis(temperature_c)
        return np.sqrt(np.einsum("...i,ij,...j->...", X, self.cov, X))

    def band(self, temperature_c) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) of the ``level`` band at temperature(s) [C]."""
        f, s = self(temperature_c), self.t_quantile * self.sd(temperature_c)
        return f - s, f + s

    @property
    def sf_tempco(self) -> float:
        """d SF / dT at t_ref over SF(t_ref) [1/K] (the IMU calibration's ``sf_tempco``)."""
        return float(self.coef[1] / self.coef[0]) if self.order >= 1 else 0.0

    def correct(self, rate, temperature_c):
        """Gyro reading divided by SF(T): the rate in the stage's (reference) units."""
        return np.asarray(rate, float) / self(temperature_c)


def fit_sf_curve(
    temperatures: Sequence[float],
    values: Sequence[float],
    boot: np.ndarray,
    order: int = 1,
    t_ref_c: float = T1,
    level: float = 0.95,
) -> SfCurve:
    """Least-squares polynomial SF(T) of ``order`` through the calibration points and its
    band (module doc): ``boot`` (B, n) bootstrap replicates of the points."""
    T = np.asarray(temperatures, float)
    y = np.asarray(values, float)
    boot = np.asarray(boot, float)
    if T.size < order + 2:
        raise ValueError(f"SF curve of order {order} needs >= {order + 2} temperatures")
    X = (T[:, None] - t_ref_c) ** np.arange(order + 1)
    pinv = np.linalg.pinv(X)
    coef = pinv @ y
    cb = boot @ pinv.T  # (B, order + 1) replicate coefficients
    cov = np.cov(cb, rowvar=False).reshape(order + 1, order + 1)
    sd = np.std(boot, axis=0, ddof=1)
    res = y - X @ coef
    dof = T.size - order - 1
    chi2 = float(np.sum((res / sd) ** 2))
    birge = max(1.0, math.sqrt(chi2 / dof))
    tq = float(student_t.ppf(0.5 + level / 2, boot.shape[0] - 1))
    return SfCurve(
        coef,
        cov * birge**2,
        float(t_ref_c),
        tq,
        birge,
        T,
        y,
        sd,
        (float(T.min()), float(T.max())),
        level=level,
    )


def sf_curve(
    model: StageModel,
    seed: int,
    plan: Plan,
    temperatures: Sequence[float] = DEFAULT_TEMPERATURES,
    stage_params: dict | None = None,
    gyro_params: dict | None = None,
    n_boot: int = 100,
    order: int = 1,
) -> dict:
    """The whole curve: :func:`calibrate_point` at every temperature, then
    :func:`fit_sf_curve`. Returns dict(points, curve)."""
    pts = [
        calibrate_point(model, T, seed, plan, stage_params, gyro_params, n_boot)
        for T in temperatures
    ]
    return {"points": pts, "curve": fit_sf_curve_points(pts, order)}


def fit_sf_curve_points(points: Sequence[CurvePoint], order: int = 1) -> SfCurve:
    """:func:`fit_sf_curve` through calibration points (their SF and bootstrap replicates)."""
    return fit_sf_curve(
        [p.temperature_c for p in points],
        [p.scale_factor for p in points],
        np.column_stack([p.boot for p in points]),
        order,
    )


# ------------------------------------------------------------------------------ YAML

FORMAT = "mems_emulator/gyro_sf_curve"


def curve_to_dict(curve: SfCurve, info: dict | None = None) -> dict:
    """The YAML mapping of a curve (format ``mems_emulator/gyro_sf_curve`` v1; fields in
    docs/stage.md)."""

    def lst(x):
        return np.asarray(x, float).tolist()

    d = {
        "format": FORMAT,
        "version": 1,
        "model": "y = SF(T) omega, SF(T) = sum_k coefficients[k] (T - t_ref_c)^k; T in degC",
        "t_ref_c": float(curve.t_ref_c),
        "method": curve.method,
        "valid_range_c": list(curve.valid_range_c),
        "gyroscope": {
            "unit": "1",
            "axis": "y",
            "scale_factor": float(curve.coef[0]),
            "sf_tempco": curve.sf_tempco,
            "coefficients": lst(curve.coef),
            "covariance": lst(curve.cov),
        },
        "band": {
            "level": float(curve.level),
            "t_quantile": float(curve.t_quantile),
            "birge_ratio": float(curve.birge),
        },
        "points": {
            "temperature_c": lst(curve.temperatures),
            "scale_factor": lst(curve.values),
            "bootstrap_sd": lst(curve.boot_sd),
        },
    }
    if info:
        d["info"] = dict(info)
    return d


def curve_from_dict(d) -> SfCurve:
    """A curve from the mapping of :func:`curve_to_dict`; ValueError naming the field."""
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise ValueError(f"not a gyro SF curve: 'format' must be {FORMAT!r}")
    try:
        g = d["gyroscope"]
        coef = np.asarray(g["coefficients"], float)
        cov = np.asarray(g["covariance"], float).reshape(coef.size, coef.size)
        band = d.get("band") or {}
        pts = d.get("points") or {}
        return SfCurve(
            coef,
            cov,
            float(d["t_ref_c"]),
            float(band.get("t_quantile", 1.96)),
            float(band.get("birge_ratio", 1.0)),
            np.asarray(pts.get("temperature_c", []), float),
            np.asarray(pts.get("scale_factor", []), float),
            np.asarray(pts.get("bootstrap_sd", []), float),
            tuple(float(v) for v in d["valid_range_c"]),
            str(d.get("method", "loaded")),
            float(band.get("level", 0.95)),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"gyro SF curve: bad or missing field ({exc})") from None


def save_yaml(curve: SfCurve, path: str | Path, info: dict | None = None) -> None:
    """Write ``curve`` as YAML (:func:`curve_to_dict`), whole or not at all and never through
    a symbolic link (:func:`mems_sim.bag.output_paths.write_output`; a scenario's output
    beside its MCAP file, replaced); BagWriteError (an OSError, one line) when it cannot."""
    import yaml

    from mems_sim.bag.output_paths import write_output

    text = yaml.safe_dump(curve_to_dict(curve, info), sort_keys=False)
    write_output(path, lambda tmp: Path(tmp).write_text(text), overwrite=True)


def load_yaml(path: str | Path) -> SfCurve:
    """Read a curve YAML (:func:`curve_from_dict`)."""

    return curve_from_dict(bounded_yaml.load_file(path))


#: evaluation range [C] and its test temperatures (1 K apart)
RANGE_C = (20.0, 45.0)
TEST_TEMPERATURES = np.arange(20.0, 45.0 + 1e-9, 1.0)
#: max |SF_fit(T) / SF_true(T) - 1| over the range [ppm] (twice the per-point target)
MAX_DEV_TARGET_PPM = 600.0
#: share of the test temperatures with the true curve inside the 95 % band
COVER_TARGET = 0.85


def evaluate_curve(curve, gyro_params: dict | None = None, temps=TEST_TEMPERATURES) -> dict:
    """The fitted curve against the gyro's true k_I(T) on the test temperatures: deviation
    [ppm] per T, max |deviation|, true curve inside the band (bool per T), half width of the
    band [ppm]."""
    g = MemsGyro(gyro_params)
    true = np.array([g.scale_factor(T) for T in temps])
    lo, hi = curve.band(temps)
    dev = (curve(temps) / true - 1.0) * 1e6
    return {
        "temperatures": np.asarray(temps),
        "true": true,
        "deviation_ppm": dev,
        "max_dev_ppm": float(np.max(np.abs(dev))),
        "inside": (true >= lo) & (true <= hi),
        "half_width_ppm": (hi - lo) / 2 / true * 1e6,
        "sf_tempco_true": float(g.params["gyro_sf_tempco_per_k"]),
    }


def sf_curve_study(
    seed: int,
    plan: Plan | None = None,
    stage_params: dict | None = None,
    gyro_params: dict | None = None,
    temperatures=DEFAULT_TEMPERATURES,
    n_boot: int = 100,
    order: int = 1,
) -> dict:
    """Identification at 22.9 C (:func:`identify_stage`), the curve (:func:`sf_curve`) and its
    evaluation against the gyro's true k_I(T) (:func:`evaluate_curve`): dict(points, curve,
    model, gyro_params, evaluation, ...)."""
    plan = plan or Plan()
    model, _ = identify_stage(seed, plan, stage_params)
    res = sf_curve(model, seed, plan, temperatures, stage_params, gyro_params, n_boot, order)
    res["model"] = model
    res["gyro_params"] = gyro_params
    res["evaluation"] = evaluate_curve(res["curve"], gyro_params)
    return res
