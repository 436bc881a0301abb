"""ROS 2 node: causal threshold detector + hybrid EKF (Table 4.1) on the micro-scanner's y_cap.

Subscribes ``<device>/adc`` (AdcFrame, one channel ``y_cap`` [V], the ``dc_transimpedance``
front end) and ``<device>/drive`` (SignalFrame with channel ``v_drive`` [V]) -- ``<device>/``
is ``device_namespace``, or nothing: relative names in the node's namespace, default
``/scanner`` --, pairs them by ``first_sample_index`` and runs per frame:

* :class:`mems_estimation.filters.scanner_threshold_detector.OnlineThresholdDetector` (DOG + NMS, latency
  W + M samples),
* :class:`mems_estimation.filters.scanner_threshold_ekf.StreamingScannerEkf` with the detections (hybrid),
  and, if ``run_plain``, a second one without them (plain EKF of Table 4.1).

Publishes (estimates are *final*: they lag the input by the filter's ``lag`` samples, their
``first_sample_index`` says which samples they are; the last ``lag`` are published once the
device's end-of-stream record announces the end of the input and every frame of it is done,
or at shutdown):
    ``<device>/estimate``              StateEstimate "hybrid_ekf": theta [rad], omega [rad/s]
    ``<device>/estimate_plain``        StateEstimate "ekf" (if run_plain)
    ``<device>/threshold_detections``  SignalFrame aligned with the input frames (one row per
        input sample k = arrival): channels ref_index (the sample the detection issued at k
        refers to, -1 if none), delta [samples] (sub-sample offset), timing_var [samples^2]
        (eq. (65) estimate); zeros where ref_index = -1
    ``/diagnostics``  frames, rejected frames, gaps, detections applied/gated, the running
        SNR of y_cap and a WARN "low signal" when it is below ``low_snr`` (no motion).

Model: ``params_yaml`` names the identified model's YAML
(:mod:`mems_estimation.identification.scanner_threshold_identification`, written by the bench
identification of scenario ``scanner_threshold``); its values replace the model parameters
and are the node's reported parameters. Empty: the parameters as given (their defaults are
the emulator's nominal table: the ``oracle`` model).

Input path: :class:`EstimatorNode`. Over a gap the filters continue as if the samples
were consecutive; the estimates keep the input's sample indices (a message never spans a
gap), also over a jump ahead beyond ``max_gap_samples`` (a counted stream reset). A
stream that started again, or a divergence of either EKF (non-finite state or covariance not
positive definite; counted ``divergences``, that frame's outputs not published), starts
both EKFs again from their prior (the pending ``lag`` estimates become the prior;
detections of earlier samples are too late).
"""

from __future__ import annotations

import bisect

import numpy as np

from mems_estimation.filters.scanner_threshold_detector import (
    DETECTOR_SPECS,
    OnlineThresholdDetector,
)
from mems_estimation.filters.scanner_threshold_ekf import EKF_SPECS, StreamingScannerEkf, signal_snr
from mems_estimation.identification.scanner_threshold_identification import load_identification
from mems_estimation.nodes.frame_input import (
    DEVICE_NAMESPACE,
    Diverged,
    EstimatorNode,
    drive_channels,
    input_specs,
    output_frame,
)
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.kernels.divergence import state_ok
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import (
    FrameError,
    adc_physical,
    index_to_ns,
    make_signal_frame,
    make_state_estimate,
)
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_QOS

NODE_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec(
        "params_yaml",
        "",
        "-",
        "identified model YAML (scanner_threshold_identification): its model_* values, "
        "R_s, V_bias, fs and r_cap replace the parameters' (empty: the parameters as given, "
        "by default the nominal device's: the oracle model)",
        "Chen 2018 Sec. 4.4.2 (bench identification)",
    ),
    ParamSpec("run_plain", True, "-", "also run and publish the plain EKF (no detections)", ""),
    ParamSpec(
        "low_snr",
        0.1,
        "-",
        "running SNR of y_cap below which 'low signal' is reported",
        "chosen: SNR 1 is the lowest segment of Table 4.3",
        min=0.0,
        max=1.0e6,
    ),
    ParamSpec(
        "snr_window_s",
        0.01,
        "s",
        "window of the running SNR",
        "chosen (~6 periods)",
        min=0.0,
        max=100.0,
        min_exclusive=True,
    ),
)
_DET_SPECS = tuple(s for s in DETECTOR_SPECS if s.name != "noise_std")

STATE_NAMES = ("theta", "omega")
STATE_UNITS = ("rad", "rad/s")
DET_CHANNELS = ("ref_index", "delta", "timing_var")
DET_UNITS = ("-", "samples", "samples^2")


def detection_rows(det, first: int, n: int) -> np.ndarray:
    """(n, 3) per-arrival-sample rows [ref_index or -1, delta, timing_var] of a frame."""
    rows = np.zeros((n, 3))
    rows[:, 0] = -1.0
    k = np.asarray(det.arrival, dtype=np.int64) - first
    rows[k, 0] = det.index
    rows[k, 1] = det.delta
    rows[k, 2] = det.timing_var
    return rows


def detections_from_rows(rows: np.ndarray, first: int):
    """Inverse of :func:`detection_rows` over a concatenated record starting at ``first``."""
    from mems_estimation.filters.scanner_threshold_detector import Detections

    k = np.flatnonzero(rows[:, 0] >= 0)
    return Detections(
        rows[k, 0].astype(np.int64),
        (k + first).astype(np.int64),
        rows[k, 1],
        np.zeros(k.size),
        rows[k, 2],
    )


def _y_cap(msg: AdcFrame) -> np.ndarray:
    """y_cap [V] of a one-channel AdcFrame; FrameError for other channels."""
    if list(msg.channel_names) != ["y_cap"]:
        raise FrameError(
            f"adc frame at {msg.first_sample_index}: expected one channel "
            f"'y_cap', got {list(msg.channel_names)}",
            "foreign",
        )
    return np.ascontiguousarray(adc_physical(msg)[:, 0])


def _v_drive(msg: SignalFrame) -> np.ndarray:
    """v_drive [V] of a drive frame; FrameError when absent or non-finite."""
    return drive_channels(msg, ("v_drive",))[0]


class ScannerThresholdEkfNode(EstimatorNode):
    """Threshold detector + hybrid (and plain) EKF of the chapter-4 micro-scanner."""

    GAP_NOTE = "the filters continue as if the samples were consecutive"

    NODE_NAME = "scanner_threshold_ekf"
    DEFAULT_NAMESPACE = "scanner"
    SPECS = NODE_SPECS + EKF_SPECS + _DET_SPECS + input_specs()
    DIAGNOSTICS_TITLE = "threshold hybrid EKF"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        p = self.p
        if p["params_yaml"]:
            # the node runs with (and reports) the identified model
            p.update(self.parameter_file("params_yaml", load_identification))
        ekf = self.values_of(EKF_SPECS)
        det = self.values_of(_DET_SPECS)
        det["noise_std"] = float(np.sqrt(p["r_cap"]))
        self.detector = OnlineThresholdDetector(**det)
        if p["lag"] <= self.detector.latency:
            raise ParameterError(
                f"parameter 'lag' = {p['lag']!r} is out of range: must exceed "
                f"the detector latency {self.detector.latency} samples"
            )
        self.hybrid = StreamingScannerEkf(ekf)
        self.plain = StreamingScannerEkf(ekf) if p["run_plain"] else None
        self.fs = p["sample_rate_hz"]
        self.pub_hyb = self.create_publisher(
            StateEstimate, self.device_topic("estimate"), FRAME_QOS
        )
        self.pub_plain = (
            self.create_publisher(StateEstimate, self.device_topic("estimate_plain"), FRAME_QOS)
            if self.plain is not None
            else None
        )
        self.pub_det = self.create_publisher(
            SignalFrame, self.device_topic("threshold_detections"), FRAME_QOS
        )
        self.low_signal = False
        self.snr = float("nan")
        self._ybuf = np.zeros(0)
        self.diag.counters["detector_latency_samples"] = self.detector.latency
        self.diag.counters["estimate_lag_samples"] = self.hybrid.lag
        # (filter sample index, input sample index) where each run of consecutive input
        # samples starts: the filters count samples without gaps, the estimates carry the
        # input's indices
        self._segments: list[tuple[int, int]] = []
        self._epoch_ns = 0  # time of input sample 0 [ns] (from the last frame taken)
        self._stream_next: int | None = None
        self.subscribe_pair(("adc", AdcFrame, _y_cap), ("drive", SignalFrame, _v_drive))
        self.flushed = False
        self.follow_end_of_stream("adc")

    def _update_snr(self, y: np.ndarray) -> None:
        w = max(1, int(self.p["snr_window_s"] * self.fs))
        self._ybuf = np.concatenate((self._ybuf, y))[-w:]
        if self._ybuf.size < w:
            return
        self.snr = signal_snr(self._ybuf, float(np.sqrt(self.p["r_cap"])))
        self.diag.counters["snr"] = round(self.snr, 3)
        low = self.snr < self.p["low_snr"]
        if low and not self.low_signal:
            self.diag.count("low_signal_events")
            self.diag.warn(
                f"low signal: y_cap SNR {self.snr:.3g} < {self.p['low_snr']} -- no "
                "scanner motion (drive far from parametric resonance?); estimates "
                "are prior-dominated, no threshold detections"
            )
        self.low_signal = low

    def _publish(self, pub, est_name, first, x, P) -> None:
        """Publish the estimates of filter samples first.. (one message per run of
        consecutive input indices)."""
        if x.shape[0] == 0:
            return
        var = np.column_stack([P[:, 0], P[:, 2]])
        for a, b, index in self._stream_spans(first, x.shape[0]):
            pub.publish(
                output_frame(
                    make_state_estimate,
                    x[a:b],
                    var[a:b],
                    first=index,
                    fs=self.fs,
                    stamp_ns=index_to_ns(index, self.fs, self._epoch_ns),
                    estimator=est_name,
                    state_names=STATE_NAMES,
                    state_units=STATE_UNITS,
                    frame_id="scanner",
                )
            )

    def _stream_spans(self, first: int, n: int) -> list[tuple[int, int, int]]:
        """Rows [a, b) of n estimates of filter samples first.. and the input index of row
        a, split where the input skipped (gap or stream reset)."""
        segs = self._segments or [(0, 0)]
        spans = []
        for j, (k0, s0) in enumerate(segs):
            k1 = segs[j + 1][0] if j + 1 < len(segs) else None
            a = max(first, k0)
            b = first + n if k1 is None else min(first + n, k1)
            if b > a:
                spans.append((a - first, b - first, s0 + a - k0))
        return spans

    def _stream_index(self, k: np.ndarray) -> np.ndarray:
        """Input sample indices (as float64, the detection rows' type) of filter sample
        indices k."""
        starts = [seg[0] for seg in self._segments]
        out = np.empty(len(k))
        for i, kk in enumerate(np.asarray(k, dtype=np.int64).tolist()):
            k0, s0 = self._segments[max(bisect.bisect_right(starts, kk) - 1, 0)]
            out[i] = float(s0 + kk - k0)
        return out

    def _note_input(self, first: int, n: int) -> None:
        """Record where the input's indices run on from the filters' (before a frame)."""
        k = self.hybrid.next_index
        if first != self._stream_next and (self._segments or first != k):
            if not self._segments and k > 0:
                self._segments.append((0, 0))
            self._segments.append((k, first))
        self._stream_next = first + n
        # keep the segments the pending (lagged) estimates may still need
        lo = k - self.hybrid.lag
        while len(self._segments) > 1 and self._segments[1][0] <= lo:
            self._segments.pop(0)

    def on_stream_reset(self, ahead: bool) -> None:
        """A jump ahead is taken as a gap (the scanner ran on, unseen: the filters
        continue as if the samples were consecutive); a stream that started again (a
        scanner that starts at rest) starts both EKFs again from their prior."""
        if not ahead:
            self.reset_estimator()

    def reset_estimator(self) -> None:
        """Both EKFs start again from their prior at the current sample."""
        self.hybrid.reset()
        if self.plain is not None:
            self.plain.reset()

    def process_pair(self, first: int, stamp_ns: int, y: np.ndarray, v: np.ndarray) -> None:
        """Detector, hybrid (and plain) EKF on one frame; publish the final estimates."""
        if self.flushed:  # input after its announced end: the filters start again
            self.flushed = False
            self.reset_estimator()
        k0 = self.hybrid.next_index  # the filters' (and the detector's) sample index
        # the input's epoch: the (lagged) estimates are stamped on the input's timeline
        self._epoch_ns = stamp_ns - index_to_ns(first, self.fs)
        self._note_input(first, y.size)
        self._update_snr(y)
        det = self.detector.process(y)
        f, x, P, _ = self.hybrid.process(y, v, det)
        if self.plain is not None:
            f2, x2, P2, _ = self.plain.process(y, v)
        bad = [
            name
            for name, filt, xx, PP in (
                ("hybrid EKF", self.hybrid, x, P),
                ("plain EKF", self.plain, x2 if self.plain else x, P2 if self.plain else P),
            )
            if filt is not None and (filt.diverged() or not state_ok(xx, PP))
        ]
        if bad:
            self.reset_estimator()
            raise Diverged(" and ".join(bad))
        self._publish(self.pub_hyb, "hybrid_ekf", f, x, P)
        if self.plain is not None:
            self._publish(self.pub_plain, "ekf", f2, x2, P2)
        rows = detection_rows(det, k0, y.size)
        if self._segments and det.index.size:
            hit = rows[:, 0] >= 0
            rows[hit, 0] = self._stream_index(rows[hit, 0].astype(np.int64))
        self.pub_det.publish(
            output_frame(
                make_signal_frame,
                rows,
                first=first,
                fs=self.fs,
                stamp_ns=stamp_ns,
                channel_names=DET_CHANNELS,
                channel_units=DET_UNITS,
                frame_id="scanner",
            )
        )
        if det.index.size:
            self.diag.count("detections", int(det.index.size))
        c = self.hybrid.counts
        for key in ("applied", "gated", "too_late"):
            self.diag.counters[f"detections_{key}"] = c[key]
        if not (c["min_det"] > 0):
            self.diag.warn("covariance lost positive definiteness")

    def input_ended(self) -> None:
        """The device announced the end of its stream and the node is done with all of
        it: publish the last ``lag`` final estimates now, not at shutdown."""
        self.flush()

    def flush(self) -> None:
        """Publish the last ``lag`` final estimates (end of the input stream; once: a
        second call publishes nothing until new input arrives)."""
        if self.flushed or self.hybrid.next_index == 0:
            return
        f, x, P = self.hybrid.flush()
        self._publish(self.pub_hyb, "hybrid_ekf", f, x, P)
        if self.plain is not None:
            f2, x2, P2 = self.plain.flush()
            self._publish(self.pub_plain, "ekf", f2, x2, P2)
        self.flushed = True

    def close(self) -> None:
        """On shutdown: publish the pending estimates."""
        if not getattr(self, "flushed", True):
            try:
                self.flush()
            except Exception:
                pass


def main(argv: list[str] | None = None) -> int:
    """Entry point ``scanner_threshold_ekf_node``."""
    return run_node(ScannerThresholdEkfNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
