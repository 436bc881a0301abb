"""Threshold-crossing detector: derivative-of-Gaussian (DOG) filter + non-maximum suppression.

Source: Y. Chen, "High-accuracy Motion Estimation for MEMS Devices with Capacitive Sensors",
PhD thesis, U. Michigan 2018, chapter 4: Sec. 4.2.2 (DOG filter for the instant of maximum
rate of change of y_cap at the threshold angle, Fig. 4.2), eq. (65) (Canny's timing-error
variance), Sec. 4.4.1 (DOG filter + non-maximum suppression; the paper ran it offline and
proposed a buffer for near real time), Table 4.2 (w_DOG = 400 samples, sigma_DOG = 15
samples).

Filter (sample units, m = -W..W, W = w_DOG // 2)::

    f[m] = -m / (sqrt(2 pi) sigma^3) exp(-m^2 / (2 sigma^2))        (derivative of a unit Gaussian)
    r[c] = sum_m f[m] y[c - m]                                       (~ d/dk of the smoothed y) [V/sample]

With y_cap = h_cap(theta) omega (eq. (71)) the crossing of theta_th gives
dy/dt = h_cap'(theta_th) omega^2 > 0 in both directions of motion (h_cap' = -R_s V_bias C_s''
and C_s'' < 0 at the maximum), so every crossing is a *positive* maximum of r, while the
turning points (omega = 0) give negative r.  A detection at centre c requires

    r[c] > kappa * sigma_r,   sigma_r = sigma_n sqrt(sum f^2)  (noise-only std of r), and
    r[c] > r[c'] for c - M <= c' < c,  r[c] >= r[c'] for c < c' <= c + M     (NMS, half-window M).

Causality: r[c] needs y up to c + W, the NMS needs r up to c + M, so the detection of
centre c is issued when sample k = c + W + M arrives: a fixed latency L = W + M samples
(0.6 ms for the defaults W = 200, M = 100 at 500 kHz).  Each detection carries ``index`` = c
(the sample it refers to), ``arrival`` = k, the response r[c] and a sub-sample offset
delta in [-0.5, 0.5] from the parabola through r[c-1], r[c], r[c+1], and its timing variance
from the discrete form of eq. (65): var(delta) ~ sigma_n^2 sum g^2 / r''(c)^2 with g the
central difference of f (noise of r'(c)) and r''(c) = r[c-1] - 2 r[c] + r[c+1] (samples^2).

Implementation: per frame, r is computed for the centres completed by the frame from the
stored 2W-sample history + the frame (direct convolution, or FFT for frames of >= 2048
samples: same values up to rounding), then an online NMS kernel (numba) keeps the last 2M+1
responses.  The offline (non-causal) run applies the same f and NMS to a whole record.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
import scipy.signal

from mems_sim.params import ParameterError, ParamSpec, resolve

__all__ = [
    "DETECTOR_SPECS",
    "dog_kernel",
    "noise_response_std",
    "Detections",
    "OnlineThresholdDetector",
    "dog_filter_offline",
    "detect_offline",
    "canny_timing_variance",
    "slope_noise_var",
]

DETECTOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "dog_sigma",
        15.0,
        "samples",
        "standard deviation sigma_DOG of the DOG filter",
        "Chen 2018 Table 4.2 (15)",
        min=0.5,
        max=1.0e4,
    ),
    ParamSpec(
        "dog_width",
        400,
        "samples",
        "filter size w_DOG (half width W = w_DOG // 2)",
        "Chen 2018 Table 4.2 (400)",
        min=2,
        max=100_000,
    ),
    ParamSpec(
        "nms_half_window",
        100,
        "samples",
        "non-maximum-suppression half window M",
        "chosen: < a quarter of the 800-sample period at 625 Hz, 500 kHz",
        min=1,
        max=100_000,
    ),
    ParamSpec(
        "detect_kappa",
        4.0,
        "-",
        "detection threshold on r in units of its noise-only std",
        "chosen (~0.1 false alarms/s on pure noise at 500 kHz)",
        min=0.0,
        max=1.0e3,
    ),
    ParamSpec(
        "noise_std",
        0.0435,
        "V",
        "readout noise std sigma_n assumed by the detector",
        "Chen 2018 Table 4.2",
        min=0.0,
        max=100.0,
        min_exclusive=True,
    ),
)


def dog_kernel(sigma: float, width: int) -> np.ndarray:
    """f[m], m = -W..W (W = width // 2): first derivative of a unit-area Gaussian [1/sample^2].

    Raises:
        ParameterError: if the half width is below 3 sigma (truncated edge response).
    """
    W = int(width) // 2
    if W < 3.0 * sigma:
        raise ParameterError(
            f"parameter 'dog_width' = {width!r} is out of range: must be >= "
            f"6 dog_sigma = {6 * sigma!r} samples"
        )
    m = np.arange(-W, W + 1, dtype=np.float64)
    return -m / (math.sqrt(2.0 * math.pi) * sigma**3) * np.exp(-m * m / (2.0 * sigma * sigma))


def noise_response_std(sigma_n: float, kernel: np.ndarray) -> float:
    """Std of r for white input noise sigma_n [V]: sigma_n sqrt(sum f^2)."""
    return float(sigma_n * math.sqrt(float(np.sum(kernel * kernel))))


def canny_timing_variance(sigma_n: float, kernel: np.ndarray, y_clean: np.ndarray, c: int) -> float:
    """Discrete form of eq. (65): R_t = sigma_n^2 sum f'^2 / (sum f' y'(-.))^2 [samples^2].

    Evaluated at centre ``c`` of the noiseless record ``y_clean`` (needs c +- W inside).
    Equivalent statement: var(delta c) ~ var(r'(c)) / r''(c)^2 for the NMS peak.
    """
    W = (kernel.shape[0] - 1) // 2
    fp = np.gradient(kernel)
    seg = y_clean[c - W - 1 : c + W + 2]
    rpp = np.convolve(seg, np.gradient(fp), mode="valid")
    mid = rpp.shape[0] // 2
    return float(sigma_n**2 * np.sum(fp * fp) / rpp[mid] ** 2)


class Detections(NamedTuple):
    """Threshold detections (arrays of equal length).

    index: sample c the detection refers to.  arrival: sample at which it was issued
    (c + latency online, = index offline).  delta: sub-sample offset of the peak [samples].
    response: r[c] [V/sample].  timing_var: eq. (65) estimate of var(detected time) [samples^2].
    """

    index: np.ndarray
    arrival: np.ndarray
    delta: np.ndarray
    response: np.ndarray
    timing_var: np.ndarray

    @staticmethod
    def empty() -> Detections:
        """No detection."""
        return Detections(
            np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0)
        )

    @staticmethod
    def concat(parts) -> Detections:
        """Concatenate a sequence of :class:`Detections`."""
        parts = list(parts)
        if not parts:
            return Detections.empty()
        return Detections(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in Detections._fields)
        )


@numba.njit(cache=True)
def _parabolic_delta(rm, r0, rp):
    den = rm - 2.0 * r0 + rp
    if den >= 0.0:
        return 0.0
    d = 0.5 * (rm - rp) / den
    return min(0.5, max(-0.5, d))


@numba.njit(cache=True)
def _timing_var(rm, r0, rp, g2):
    """var(delta) = g2 / r''^2 (eq. (65), discrete); g2 = sigma_n^2 sum g^2 [V^2/sample^2]."""
    curv = rm - 2.0 * r0 + rp
    if curv >= 0.0:
        return 1.0e6
    return min(1.0e6, g2 / (curv * curv))


def slope_noise_var(sigma_n: float, kernel: np.ndarray) -> float:
    """Variance of r'(c) = (r[c+1] - r[c-1])/2 for white input noise sigma_n: sigma_n^2 sum g^2."""
    g = 0.5 * (np.concatenate((kernel[1:], [0.0])) - np.concatenate(([0.0], kernel[:-1])))
    return float(sigma_n**2 * np.sum(g * g))


@numba.njit(cache=True)
def _nms_run(r, c_first, W, M, thr, g2, rbuf, out_c, out_k, out_d, out_r, out_v):
    """Online non-maximum suppression over new responses r[i] of centres c_first + i.

    The response of centre c1 exists once sample c1 + W has arrived; the NMS of centre
    c = c1 - M is decided then, at arrival k = c + M + W.  rbuf: ring of the last 2M+1
    responses (slot c % (2M+1)).  Returns the number of detections written.
    """
    nr = rbuf.shape[0]
    nd = 0
    for i in range(r.shape[0]):
        c1 = c_first + i
        rbuf[c1 % nr] = r[i]
        c = c1 - M
        if c - M < W:
            continue
        r0 = rbuf[c % nr]
        if r0 <= thr:
            continue
        ok = True
        for j in range(1, M + 1):
            if rbuf[(c - j) % nr] >= r0 or rbuf[(c + j) % nr] > r0:
                ok = False
                break
        if ok:
            out_c[nd] = c
            out_k[nd] = c1 + W
            out_d[nd] = _parabolic_delta(rbuf[(c - 1) % nr], r0, rbuf[(c + 1) % nr])
            out_r[nd] = r0
            out_v[nd] = _timing_var(rbuf[(c - 1) % nr], r0, rbuf[(c + 1) % nr], g2)
            nd += 1
    return nd


#: frames at least this long are filtered by FFT (overlap-save), shorter ones directly
FFT_MIN_SAMPLES = 2048


class OnlineThresholdDetector:
    """Causal, online DOG + NMS detector with a fixed latency of W + M samples.

    Args:
        dog_sigma [samples], dog_width [samples], nms_half_window [samples],
        detect_kappa [-], noise_std [V]: see :data:`DETECTOR_SPECS`.
    """

    def __init__(self, **overrides):
        self.p = resolve(DETECTOR_SPECS, overrides)
        self.kernel = dog_kernel(self.p["dog_sigma"], self.p["dog_width"])
        self.W = (self.kernel.shape[0] - 1) // 2
        self.M = int(self.p["nms_half_window"])
        #: latency in samples: detection of centre c issued at sample c + latency
        self.latency = self.W + self.M
        self.threshold = self.p["detect_kappa"] * noise_response_std(
            self.p["noise_std"], self.kernel
        )
        self._g2 = slope_noise_var(self.p["noise_std"], self.kernel)
        self._hist = np.zeros(0)  # last 2W inputs (the filter's causal history)
        self._rbuf = np.zeros(2 * self.M + 1)
        self.next_index = 0

    def process(self, y: np.ndarray) -> Detections:
        """Feed the next frame of y_cap [V]; returns the detections issued during it.

        The responses r[c] completed by this frame (c + W inside it) are computed from the
        stored history and the frame only (causal), by direct or FFT convolution.
        """
        y = np.ascontiguousarray(y, dtype=np.float64)
        n = y.shape[0]
        nf = self.kernel.shape[0]
        ext = np.concatenate((self._hist, y))
        start = self.next_index - self._hist.shape[0]  # global index of ext[0]
        self._hist = ext[-(nf - 1) :].copy() if ext.shape[0] >= nf - 1 else ext
        self.next_index += n
        if ext.shape[0] < nf:
            return Detections.empty()
        if n >= FFT_MIN_SAMPLES:
            r = scipy.signal.fftconvolve(ext, self.kernel, mode="valid")
        else:
            r = np.convolve(ext, self.kernel, mode="valid")
        cap = r.shape[0] // (self.M + 1) + 2
        oc = np.empty(cap, np.int64)
        ok = np.empty(cap, np.int64)
        od = np.empty(cap)
        orr = np.empty(cap)
        ov = np.empty(cap)
        nd = _nms_run(
            np.ascontiguousarray(r),
            start + self.W,
            self.W,
            self.M,
            self.threshold,
            self._g2,
            self._rbuf,
            oc,
            ok,
            od,
            orr,
            ov,
        )
        return Detections(
            oc[:nd].copy(), ok[:nd].copy(), od[:nd].copy(), orr[:nd].copy(), ov[:nd].copy()
        )


def dog_filter_offline(y: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Non-causal r[c] = sum_m f[m] y[c - m] for every c with a full window; NaN elsewhere."""
    y = np.asarray(y, dtype=float)
    W = (kernel.shape[0] - 1) // 2
    r = np.full(y.shape[0], np.nan)
    if y.shape[0] > 2 * W:
        r[W : y.shape[0] - W] = np.convolve(y, kernel, mode="valid")
    return r


def detect_offline(y: np.ndarray, **overrides) -> tuple[Detections, np.ndarray]:
    """Offline run of the same DOG filter + NMS over a whole record.

    Returns (detections with arrival = index, r). Same parameters as the online detector.
    """
    p = resolve(DETECTOR_SPECS, overrides)
    f = dog_kernel(p["dog_sigma"], p["dog_width"])
    M = int(p["nms_half_window"])
    thr = p["detect_kappa"] * noise_response_std(p["noise_std"], f)
    g2 = slope_noise_var(p["noise_std"], f)
    r = dog_filter_offline(y, f)
    n = r.shape[0]
    valid = np.where(np.isfinite(r), r, -np.inf)
    cand = np.where(valid > thr)[0]
    idx, dl, rr, tv = [], [], [], []
    for c in cand:
        if c - M < 0 or c + M >= n or not np.isfinite(r[c - M]) or not np.isfinite(r[c + M]):
            continue
        left = valid[c - M : c]
        right = valid[c + 1 : c + M + 1]
        if np.all(left < r[c]) and np.all(right <= r[c]):
            idx.append(c)
            dl.append(_parabolic_delta(r[c - 1], r[c], r[c + 1]))
            rr.append(r[c])
            tv.append(_timing_var(r[c - 1], r[c], r[c + 1], g2))
    idx = np.asarray(idx, np.int64)
    return Detections(
        idx, idx.copy(), np.asarray(dl, float), np.asarray(rr, float), np.asarray(tv, float)
    ), r
