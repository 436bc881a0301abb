"""ROS 2 node: in-situ gyro scale-factor calibration from the stage estimate (Chen 2018
sec. 3.3.1 and 3.6.3, eq. 27).

Subscribes the stage's ``estimate`` (StateEstimate theta, omega), ``drive`` (phase,
f_drive, trial) and ``gyro/adc`` (the gyro's own-clock AdcFrame) -- the node's namespace,
default ``/stage``, or ``device_namespace`` --; pairs
the peak-to-peak rates per trial (:class:`mems_estimation.identification.stage_gyro_calibration.StreamingCalibrator`)
and publishes the stage's ``gyro_scale_factor`` (mems_msgs/CalibrationResult: scale_factor,
bias with standard errors) once ``n_trials`` trials are paired (and again at shutdown if
more arrived). Malformed / non-finite frames are rejected and counted on /diagnostics
(input path: :class:`EstimatorNode`; the gyro stream is validated and sequenced alike).
Gyro sample j of a frame is placed on the stage's sample index k = (t_j - t0) fs, t_j its
stamp and t0 the time of stage sample 0, taken from the first stage frame (drive or
estimate: t0 = stamp - first_sample_index / fs; the drive arrives live, an in-situ EKF's
estimates only after the sweep); gyro frames that arrive before any stage frame are held
until t0 is known (``gyro_frames_held``), so an epoch from the wall clock (real-time runs)
places them as one from 0. A gap or stream reset of the stage streams drops the trials in
progress and the gyro samples waiting for them (``trials_dropped``) and places the gyro
samples on the stage index again from the next frame's stamp; the gyro samples waiting for
stage data (held ones included) are bounded to ``max_unpaired_samples``
(``gyro_overflow_samples``). A pair of peak-to-peak
rates whose ratio gyro/stage is outside [:data:`MIN_RATIO`, :data:`MAX_RATIO`] (no
gyro's scale factor) or not finite is discarded (``implausible_pairs``): one absurd frame
does not spoil eq. (27).
"""

from __future__ import annotations

import numpy as np
from rclpy.duration import Duration

from mems_estimation.identification.stage_gyro_calibration import StreamingCalibrator
from mems_estimation.identification.stage_identification import harmonic_fit
from mems_estimation.nodes.frame_input import (
    DEVICE_NAMESPACE,
    EstimatorNode,
    adc_columns,
    input_specs,
)
from mems_msgs.msg import AdcFrame, CalibrationResult, SignalFrame, StateEstimate
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import FrameError, ns_to_time, signal_data, time_to_ns
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS

CAL_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec(
        "sample_rate_hz",
        625.0e3,
        "Hz",
        "stage sample rate",
        "sec. 3.5.2",
        min=0.0,
        max=1e8,
        min_exclusive=True,
    ),
    ParamSpec(
        "n_trials",
        7,
        "-",
        "trials after which the result is published",
        "eq. (24)",
        min=3,
        max=100000,
    ),
    ParamSpec(
        "half_window", 15, "samples", "+-samples around the peaks", "sec. 3.6.3", min=0, max=10000
    ),
    ParamSpec(
        "settle_fraction",
        0.5,
        "-",
        "leading fraction of each trial skipped (transient)",
        "assumption (1/(zeta wn) = 18.6 ms)",
        min=0.0,
        max=0.95,
    ),
    ParamSpec("device", "stage/gyro", "-", "device name in the result", ""),
)

#: Range of the ratio gyro / stage peak-to-peak rate of a pair that is used [-] (a MEMS
#: gyro's scale factor is within a few percent of 1; outside this the pair is absurd).
MIN_RATIO, MAX_RATIO = 0.5, 2.0


def _estimate_omega(msg: StateEstimate) -> np.ndarray:
    names = list(msg.state_names)
    if "omega" not in names:
        raise FrameError(f"estimate at {msg.first_sample_index}: no 'omega' state", "foreign")
    s = np.asarray(msg.states, float)
    if s.size != msg.num_samples * len(names):
        raise FrameError(f"estimate at {msg.first_sample_index}: size mismatch")
    if not np.all(np.isfinite(s)):
        raise FrameError(f"estimate at {msg.first_sample_index}: non-finite values", "non_finite")
    return s.reshape(msg.num_samples, len(names))[:, names.index("omega")]


def _drive_trials(msg: SignalFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(phase, f_drive, trial) of a drive frame; FrameError when absent or non-finite."""
    data = signal_data(msg)
    names = list(msg.channel_names)
    try:
        cols = [names.index(c) for c in ("phase", "f_drive", "trial")]
    except ValueError as exc:
        raise FrameError(f"drive frame at {msg.first_sample_index}: {exc}", "foreign") from None
    return tuple(np.ascontiguousarray(data[:, c]) for c in cols)


def _gyro_rate(msg: AdcFrame, codes: np.ndarray | None = None) -> np.ndarray:
    """Angular rate [rad/s] of a gyro frame (its first channel; ``codes``: the frame's
    validated codes, if known); FrameError when the conversion overflows (the values are
    then all finite)."""
    return adc_columns(msg, [0], codes)[:, 0]


class StageGyroCalibrationNode(EstimatorNode):
    """Peak-to-peak pairing + least squares eq. (27) (see module doc)."""

    NODE_NAME = "stage_gyro_calibration"
    DEFAULT_NAMESPACE = "stage"
    SPECS = CAL_SPECS + input_specs()
    DIAGNOSTICS_TITLE = "gyro scale factor"
    #: A stage stream that starts (again) at or beyond this sample index is counted from
    #: its first sample.
    BASE_INDEX = 2**50

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        #: gyro frames taken off the wire (accepted or not): lets an owner wait for them
        self.gyro_frames_received = 0
        p = self.p
        self.cal = StreamingCalibrator(p["sample_rate_hz"], p["settle_fraction"], p["half_window"])
        # load the compiled (numba) harmonic fit now, not at the first trial (~1 s)
        harmonic_fit(np.zeros(64), np.arange(64) / 64.0)
        self.pub = self.create_publisher(
            CalibrationResult, self.device_topic("gyro_scale_factor"), RESULT_QOS
        )
        self.t0_ns = None
        #: gyro frames taken before the stage's time origin is known: (stamp [ns], rate
        #: [Hz], values [rad/s]), placed once it is (:meth:`_set_origin`)
        self._held: list[tuple[int, float, np.ndarray]] = []
        self._rebase = False
        self._base: int | None = None
        self._screened = 0
        self.results: list[dict] = []
        self.last_stamp = 0
        self.estimates_received = 0
        self.subscribe_pair(
            ("estimate", StateEstimate, self._decode_estimate),
            ("drive", SignalFrame, self._decode_drive),
            check_rate=False,
        )
        self.create_subscription(AdcFrame, self.device_topic("gyro/adc"), self.on_gyro, FRAME_QOS)

    def _decode_estimate(self, msg: StateEstimate) -> np.ndarray:
        """omega of an estimate frame; the first stage frame sets the time origin."""
        om = _estimate_omega(msg)
        self._set_origin(msg)
        self.last_stamp = time_to_ns(msg.header.stamp)
        self.estimates_received += 1
        return om

    def _decode_drive(self, msg: SignalFrame) -> tuple:
        """(phase, f_drive, trial) of a drive frame; the first stage frame sets the time
        origin (the drive arrives live, before the estimates of an in-situ EKF)."""
        drive = _drive_trials(msg)
        self._set_origin(msg)
        return drive

    def _set_origin(self, msg) -> None:
        """t0 [ns], the time of stage sample 0 (of the stream's base, :meth:`process_pair`),
        from a stage frame if not known yet: t0 = stamp - (first_sample_index - base) / fs;
        then the gyro frames held for it are placed."""
        if self.t0_ns is not None:
            return
        first = int(msg.first_sample_index)
        base = first if first >= self.BASE_INDEX else 0
        self.t0_ns = time_to_ns(msg.header.stamp) - round(
            (first - base) * 1e9 / self.p["sample_rate_hz"]
        )
        held, self._held = self._held, []
        for stamp_ns, rate, v in held:
            self._place_gyro(stamp_ns, rate, v)

    def on_gyro(self, msg: AdcFrame) -> None:
        """Gyro samples, placed on the stage's sample index through their stamps; held
        while the stage's time origin is not known (bounded, module doc)."""
        self.gyro_frames_received += 1
        v = self.take_frame("gyro", msg, self._decode_gyro, check_rate=False)
        if v is None or not self.sequence(
            "gyro", msg.first_sample_index, msg.num_samples, hooks=False
        ):
            return
        stamp_ns = time_to_ns(msg.header.stamp)
        if self.t0_ns is None:
            self._hold_gyro(stamp_ns, float(msg.sample_rate_hz), v)
            return
        self._place_gyro(stamp_ns, float(msg.sample_rate_hz), v)

    def _decode_gyro(self, msg: AdcFrame) -> np.ndarray:
        return _gyro_rate(msg, self.checked_codes(msg))

    def _hold_gyro(self, stamp_ns: int, rate: float, v: np.ndarray) -> None:
        """Keep a gyro frame until the time origin is known; at most
        ``max_unpaired_samples`` samples (the oldest dropped, ``gyro_overflow_samples``)."""
        self.diag.count("gyro_frames_held")
        self._held.append((stamp_ns, rate, v))
        limit = int(self.p["max_unpaired_samples"])
        waiting = sum(h[2].size for h in self._held)
        while waiting > limit:
            stamp_ns, rate, old = self._held[0]
            drop = min(old.size, waiting - limit)
            if drop == old.size:
                self._held.pop(0)
            else:  # the frame's first samples: its stamp moves to its new first sample
                self._held[0] = (stamp_ns + round(drop * 1e9 / rate), rate, old[drop:])
            self.diag.count("gyro_overflow_samples", drop)
            waiting -= drop

    def _place_gyro(self, stamp_ns: int, rate: float, v: np.ndarray) -> None:
        """Gyro samples at stage index k = (t_j - t0) fs, t_j = stamp + j / rate."""
        t_first = (stamp_ns - self.t0_ns) / 1e9
        k = (t_first + np.arange(v.size) / rate) * self.p["sample_rate_hz"]
        self.cal.add_gyro(k, v)
        self._bound_gyro()
        self._check_done()

    def _bound_gyro(self) -> None:
        """Keep at most ``max_unpaired_samples`` gyro samples waiting for stage data."""
        cal, limit = self.cal, int(self.p["max_unpaired_samples"])
        waiting = sum(a.size for a in cal.gyro_k)
        if waiting > limit:
            cal.gyro_k = [np.concatenate(cal.gyro_k)[-limit:]]
            cal.gyro_v = [np.concatenate(cal.gyro_v)[-limit:]]
            self.diag.count("gyro_overflow_samples", waiting - limit)

    def _drop_pending(self) -> None:
        """Drop the trials in progress and the gyro samples waiting for them; place the
        gyro on the stage index again from the next stage frame."""
        if self.cal.trials:
            self.diag.count("trials_dropped", len(self.cal.trials))
        self.cal.trials.clear()
        self.cal.gyro_k, self.cal.gyro_v, self.cal.gyro_end = [], [], -1.0
        self._rebase = True

    def on_gap(self, gap: int) -> None:
        """The trials in progress are incomplete: dropped (:meth:`_drop_pending`)."""
        self._drop_pending()

    def reset_estimator(self) -> None:
        """Stream reset: as a gap (:meth:`_drop_pending`); the pairs so far are kept."""
        self._drop_pending()

    def process_pair(self, first: int, stamp_ns: int, om: np.ndarray, drive) -> None:
        """One trial's worth of rate estimate with its drive phase, frequency, trial."""
        if self._base is None or self._rebase:
            # the stage index the trials count from: 0, or the first of a stream that
            # (re)starts beyond BASE_INDEX (float64 cannot place samples that far)
            self._base = first if first >= self.BASE_INDEX else 0
            if self._rebase or self._base:
                fs = self.p["sample_rate_hz"]
                self.t0_ns = stamp_ns - round((first - self._base) * 1e9 / fs)
            self._rebase = False
        ph, fd, tr = drive
        self.cal.add_stage(first - self._base, om, ph, fd, tr.astype(np.int64))
        self._check_done()

    def _screen_pairs(self) -> None:
        """Discard new pairs whose gyro/stage peak-to-peak ratio is not plausible."""
        pairs = self.cal.pairs
        k = self._screened
        while k < len(pairs):
            s, g = pairs[k]["stage_pp"], pairs[k]["gyro_pp"]
            ok = np.isfinite(s) and np.isfinite(g) and s > 0 and MIN_RATIO <= g / s <= MAX_RATIO
            if ok:
                k += 1
                continue
            del pairs[k]
            self.diag.count("implausible_pairs")
            self.diag.warn(
                f"trial pair discarded: gyro/stage peak-to-peak {g!r}/{s!r} outside "
                f"[{MIN_RATIO}, {MAX_RATIO}]"
            )
        self._screened = k

    def _check_done(self) -> None:
        self._screen_pairs()
        if len(self.cal.pairs) >= self.p["n_trials"] and len(self.results) == 0:
            self.publish_result()

    def publish_result(self) -> dict | None:
        """Publish eq. (27) over the pairs so far; None with fewer than 3 pairs."""
        try:
            res = self.cal.result()
        except ValueError:
            return None
        m = CalibrationResult()
        m.header.stamp = ns_to_time(self.last_stamp)
        m.header.frame_id = "imu_link"
        m.device = self.p["device"]
        m.method = "least_squares_eq27_peak_to_peak"
        m.names = ["scale_factor", "bias"]
        m.units = ["1", "rad/s"]
        m.values = [res["scale_factor"], res["bias"]]
        m.standard_errors = [res["scale_factor_se"], res["bias_se"]]
        m.num_points = res["n"]
        m.residual_rms = res["residual_rms"]
        m.residual_unit = "rad/s"
        self.pub.publish(m)
        self.results.append(res)
        self.diag.count("results")
        return res

    def close(self) -> None:
        """At shutdown: process the remaining trials and publish if new pairs arrived."""
        n = len(self.cal.pairs)
        self.cal.finish()
        self._screen_pairs()
        if len(self.cal.pairs) > n or not self.results:
            if self.publish_result() is not None:
                # the process may end right after: let the subscribers (recorder) have it
                self.pub.wait_for_all_acked(Duration(seconds=2.0))


def main(argv: list[str] | None = None) -> int:
    """Entry point ``stage_gyro_calibration_node``."""
    return run_node(StageGyroCalibrationNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
