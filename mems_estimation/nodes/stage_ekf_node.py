"""ROS 2 node: EKF motion estimator of the micro-stage (Chen 2018 eqs. 48-53).

Subscribes the stage's ``adc`` (capacitive channels, AdcFrame) and ``drive`` (SignalFrame
with u, v_bias, f_drive) -- the node's namespace, default ``/stage``, or
``device_namespace`` --, pairs them by ``first_sample_index``, cancels the
feedthrough with the bias on/off periods (sec. 3.5.4), runs the EKF on the identified
parameters read from ``params_yaml`` (never the emulator's truth) and publishes
the stage's ``estimate`` (StateEstimate: theta [rad], omega [rad/s] with variances, one per
sample). Malformed or non-finite frames are rejected and counted on /diagnostics; the
estimator keeps running (time update only over a gap, cancellation history reset).
"""

from __future__ import annotations

import numpy as np

from mems_estimation.filters.stage_ekf import FeedthroughCanceller, StageEkf, load_model
from mems_estimation.nodes.frame_input import DEVICE_NAMESPACE, EstimatorNode
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import FrameError, adc_physical, make_state_estimate, signal_data
from mems_sim.ros.node_base import run_node
from mems_sim.ros.qos import FRAME_QOS

EKF_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
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


class StageEkfNode(EstimatorNode):
    """EKF on the feedthrough-cancelled capacitive channels (see module doc)."""

    GAP_NOTE = "time updates only over the gap, cancellation history reset"

    NODE_NAME = "stage_ekf"
    DEFAULT_NAMESPACE = "stage"
    SPECS = EKF_SPECS
    DIAGNOSTICS_TITLE = "stage EKF"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        p = self.p
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
        self.fs = self.model.fs
        self.ekf = StageEkf(self.model)
        self.canceller = FeedthroughCanceller(
            len(chans), self.model.fs, enabled=p["cancel_feedthrough"]
        )
        # load the compiled (numba) kernels before subscribing, not at the first frame
        # (~1 s late otherwise); throwaway filter and canceller, same argument types
        nch = len(chans)
        StageEkf(self.model).step(np.zeros((1, nch)), np.zeros(1))
        FeedthroughCanceller(nch, self.model.fs).step(np.zeros((1, nch)), np.ones(1), np.ones(1))
        self.pub = self.create_publisher(StateEstimate, self.device_topic("estimate"), FRAME_QOS)
        self.subscribe_pair(
            ("adc", AdcFrame, self._decode_adc), ("drive", SignalFrame, drive_columns)
        )

    def _decode_adc(self, msg: AdcFrame) -> np.ndarray:
        """The selected channels of an ADC frame [V]; FrameError when absent or non-finite."""
        y = adc_physical(msg)
        names = list(msg.channel_names)
        missing = [c for c in self.channels if c not in names]
        if missing:
            raise FrameError(f"adc frame at {msg.first_sample_index}: channels {missing} absent")
        y = np.ascontiguousarray(y[:, [names.index(c) for c in self.channels]])
        if not np.all(np.isfinite(y)):
            raise FrameError(f"adc frame at {msg.first_sample_index}: non-finite values")
        return y

    def on_gap(self, gap: int) -> None:
        """The EKF continues with time updates only over the missing span; the feedthrough
        cancellation starts again."""
        nch = len(self.channels)
        self.ekf.step(np.full((gap, nch), np.nan), np.zeros(gap))
        self.canceller = FeedthroughCanceller(
            nch, self.model.fs, enabled=self.p["cancel_feedthrough"]
        )

    def process_pair(self, first: int, stamp_ns: int, y: np.ndarray, drive) -> None:
        """Cancel the feedthrough, run the EKF on one frame and publish theta, omega."""
        u, vb, fd = drive
        yc = self.canceller.step(y, vb, fd)
        x, v = self.ekf.step(yc, u, corrected=self.p["output_correction"])
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
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
        self.pub.publish(msg)


def main(argv: list[str] | None = None) -> int:
    """Entry point ``stage_ekf_node``."""
    return run_node(StageEkfNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
