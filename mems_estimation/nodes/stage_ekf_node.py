"""ROS 2 node: EKF motion estimator of the micro-stage (Chen 2018 eqs. 48-53).

Subscribes ``<stage>/adc`` (capacitive channels, AdcFrame) and ``<stage>/drive``
(SignalFrame with u, v_bias, f_drive), pairs them by ``first_sample_index``, cancels the
feedthrough with the bias on/off periods (sec. 3.5.4), runs the EKF on the identified
parameters read from ``params_yaml`` (never the emulator's truth) and publishes
``<stage>/estimate`` (StateEstimate: theta [rad], omega [rad/s] with variances, one per
sample). Malformed or non-finite frames are rejected and counted on /diagnostics; the
estimator keeps running (time update only over a gap, cancellation history reset).
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node

from mems_estimation.filters.stage_ekf import FeedthroughCanceller, StageEkf, load_model
from mems_estimation.nodes.frame_input import FramePairer
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.diagnostics import DiagnosticsReporter
from mems_sim.ros.frames import (
    FrameError,
    IndexTracker,
    adc_physical,
    make_state_estimate,
    signal_data,
    time_to_ns,
)
from mems_sim.ros.node_base import run_node
from mems_sim.ros.params import declare_specs
from mems_sim.ros.qos import FRAME_QOS

EKF_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("stage_namespace", "/stage", "-", "namespace of the stage's adc/drive topics", ""),
    ParamSpec(
        "params_yaml", "", "-", "identified parameter YAML (stage_identification)", "sec. 3.5.4"
    ),
    ParamSpec("channels", "1A,1B,2A,2B", "-", "capacitive channels used (1 to 4)", "eq. (50)"),
    ParamSpec(
        "cancel_feedthrough", True, "-", "bias on/off feedthrough cancellation", "sec. 3.5.4"
    ),
    ParamSpec(
        "output_correction",
        True,
        "-",
        "apply the identified alpha/beta correction",
        "sec. 3.5.4 (last step)",
    ),
)


def drive_columns(msg: SignalFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v_bias, f_drive) of a drive frame; FrameError when absent or non-finite."""
    data = signal_data(msg)
    names = list(msg.channel_names)
    for c in ("u", "v_bias", "f_drive"):
        if c not in names:
            raise FrameError(f"drive frame at {msg.first_sample_index}: no '{c}' channel")
    return tuple(np.ascontiguousarray(data[:, names.index(c)]) for c in ("u", "v_bias", "f_drive"))


class StageEkfNode(Node):
    """EKF on the feedthrough-cancelled capacitive channels (see module doc)."""

    def __init__(self, **node_kwargs) -> None:
        super().__init__("stage_ekf", **node_kwargs)
        self.p = p = declare_specs(self, EKF_SPECS)
        try:
            model = load_model(p["params_yaml"])
        except (FileNotFoundError, ValueError) as exc:
            raise ParameterError(
                f"parameter 'params_yaml' = {p['params_yaml']!r} is invalid: {exc}"
            ) from None
        chans = tuple(c.strip() for c in p["channels"].split(",") if c.strip())
        if (
            not chans
            or any(c not in model.channels for c in chans)
            or len(set(chans)) != len(chans)
        ):
            raise ParameterError(
                f"parameter 'channels' = {p['channels']!r} is invalid: allowed "
                f"1 to {len(model.channels)} distinct of {model.channels}"
            )
        self.channels = chans
        self.model = model.select(chans)
        self.ekf = StageEkf(self.model)
        self.canceller = FeedthroughCanceller(
            len(chans), self.model.fs, enabled=p["cancel_feedthrough"]
        )
        # load the compiled (numba) kernels before subscribing, not at the first frame
        # (~1 s late otherwise); throwaway filter and canceller, same argument types
        nch = len(chans)
        StageEkf(self.model).step(np.zeros((1, nch)), np.zeros(1))
        FeedthroughCanceller(nch, self.model.fs).step(np.zeros((1, nch)), np.ones(1), np.ones(1))
        ns = p["stage_namespace"].rstrip("/")
        self.pub = self.create_publisher(StateEstimate, f"{ns}/estimate", FRAME_QOS)
        self.pairer = FramePairer()
        self.tracker = IndexTracker()
        self.stamps: dict[int, int] = {}
        self.frames_done = 0
        self.diag = DiagnosticsReporter(self, f"{self.get_name()}: stage EKF")
        self.create_subscription(AdcFrame, f"{ns}/adc", self.on_adc, FRAME_QOS)
        self.create_subscription(SignalFrame, f"{ns}/drive", self.on_drive, FRAME_QOS)

    def _reject(self, text: str) -> None:
        self.diag.count("rejected_frames")
        self.diag.warn(f"rejected frame: {text}")

    def _check_rate(self, msg) -> None:
        if msg.sample_rate_hz != self.model.fs:
            raise FrameError(
                f"frame at {msg.first_sample_index}: sample_rate_hz "
                f"{msg.sample_rate_hz} differs from the model's {self.model.fs} Hz"
            )

    def on_adc(self, msg: AdcFrame) -> None:
        """Validate an ADC frame (channels present, finite) and process completed pairs."""
        try:
            self._check_rate(msg)
            y = adc_physical(msg)
            names = list(msg.channel_names)
            missing = [c for c in self.channels if c not in names]
            if missing:
                raise FrameError(
                    f"adc frame at {msg.first_sample_index}: channels {missing} absent"
                )
            y = np.ascontiguousarray(y[:, [names.index(c) for c in self.channels]])
            if not np.all(np.isfinite(y)):
                raise FrameError(f"adc frame at {msg.first_sample_index}: non-finite values")
        except FrameError as exc:
            self._reject(str(exc))
            return
        self.stamps[msg.first_sample_index] = time_to_ns(msg.header.stamp)
        self._process(self.pairer.add("adc", msg.first_sample_index, y))

    def on_drive(self, msg: SignalFrame) -> None:
        """Validate a drive frame and process completed pairs."""
        try:
            self._check_rate(msg)
            cols = drive_columns(msg)
        except FrameError as exc:
            self._reject(str(exc))
            return
        self._process(self.pairer.add("drive", msg.first_sample_index, cols))

    def _process(self, pairs) -> None:
        for first, y, (u, vb, fd) in pairs:
            if y.shape[0] != u.size:
                self.stamps.pop(first, None)
                self._reject(f"frames at {first}: {y.shape[0]} samples vs {u.size} drive")
                continue
            gap = self.tracker.update(first, u.size)
            if gap:
                self.diag.count("gaps")
                self.diag.warn(f"gap of {gap} samples before index {first}")
                # the EKF continues with time updates only over the missing span
                nan = np.full((gap, y.shape[1]), np.nan)
                self.ekf.step(nan, np.zeros(gap))
                self.canceller = FeedthroughCanceller(
                    y.shape[1], self.model.fs, enabled=self.p["cancel_feedthrough"]
                )
            yc = self.canceller.step(y, vb, fd)
            x, v = self.ekf.step(yc, u, corrected=self.p["output_correction"])
            t0 = self.stamps.pop(first)
            msg = make_state_estimate(
                x,
                v,
                first,
                self.model.fs,
                estimator="ekf",
                state_names=("theta", "omega"),
                state_units=("rad", "rad/s"),
                frame_id="stage",
            )
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t0, 10**9)
            self.pub.publish(msg)
            self.frames_done += 1
            self.diag.count("frames")


def main(argv: list[str] | None = None) -> int:
    """Entry point ``stage_ekf_node``."""
    return run_node(StageEkfNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
