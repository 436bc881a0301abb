"""ROS 2 node: EKF motion estimator of the micro-stage (Chen 2018 eqs. 48-53).

Subscribes the stage's ``adc`` (capacitive channels, AdcFrame) and ``drive`` (SignalFrame
with u, v_bias, f_drive) -- the node's namespace, default ``/stage``, or
``device_namespace`` --, pairs them by ``first_sample_index``, cancels the
feedthrough with the bias on/off periods (sec. 3.5.4), runs the EKF on the identified
parameters read from ``params_yaml`` (never the emulator's truth) and publishes
the stage's ``estimate`` (StateEstimate: theta [rad], omega [rad/s] with variances, one per
sample). Malformed or non-finite frames are rejected and counted on /diagnostics; the
estimator keeps running (input path: :class:`EstimatorNode`). Over a gap of at most
:attr:`StageEkfNode.BRIDGE_TIME_CONSTANTS` time constants 1/(zeta wn) of the model the EKF
runs time updates only (in bounded chunks); after a longer gap or a jump ahead beyond
``max_gap_samples`` (the stage ran on, unseen, for many time constants) it starts again at
the forced steady state under the drive of the next frame; after a stream that started
again or a divergence (non-finite state, covariance not positive definite,
|theta| >= pi/2; counted ``divergences``, that frame's estimates not published) it starts
again from its prior;
the feedthrough cancellation history starts again in every case.
"""

from __future__ import annotations

import numpy as np

from mems_estimation.filters.stage_ekf import FeedthroughCanceller, StageEkf, load_model
from mems_estimation.nodes.frame_input import (
    DEVICE_NAMESPACE,
    Diverged,
    EstimatorNode,
    input_specs,
    output_frame,
)
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.kernels.divergence import state_ok
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
            raise FrameError(
                f"drive frame at {msg.first_sample_index}: no '{c}' channel", "foreign"
            )
    return tuple(np.ascontiguousarray(data[:, names.index(c)]) for c in ("u", "v_bias", "f_drive"))


class StageEkfNode(EstimatorNode):
    """EKF on the feedthrough-cancelled capacitive channels (see module doc)."""

    GAP_NOTE = "time updates only over the gap, cancellation history reset"

    NODE_NAME = "stage_ekf"
    DEFAULT_NAMESPACE = "stage"
    SPECS = EKF_SPECS + input_specs()
    #: Longest gap bridged by time updates, in time constants 1/(zeta wn) of the model:
    #: after it the state has forgotten all but e^-10 of what the filter knew.
    BRIDGE_TIME_CONSTANTS = 10.0
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
        self._start_forced = False
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
            raise FrameError(
                f"adc frame at {msg.first_sample_index}: channels {missing} absent", "foreign"
            )
        y = np.ascontiguousarray(y[:, [names.index(c) for c in self.channels]])
        if not np.all(np.isfinite(y)):
            raise FrameError(
                f"adc frame at {msg.first_sample_index}: non-finite values", "non_finite"
            )
        return y

    def on_gap(self, gap: int) -> None:
        """The EKF continues with time updates only over the missing span (at most
        :attr:`BRIDGE_TIME_CONSTANTS` time constants; after a longer one it starts again at
        the forced steady state under the next frame's drive); the feedthrough
        cancellation starts again."""
        m = self.model
        bridge = self.BRIDGE_TIME_CONSTANTS * m.fs / (m.zeta * m.wn)
        if gap <= bridge:
            self.ekf.time_update(gap)
        else:
            self._start_forced = True
        self.canceller.reset()

    def on_stream_reset(self, ahead: bool) -> None:
        """A jump ahead (the stage ran on unseen, longer than any bridged gap) starts the
        EKF again at the forced steady state under the next frame's drive
        (:meth:`StageEkf.start_forced`); a stream that started again (a stage that starts at
        rest), from its prior."""
        if ahead:
            self.on_gap(2**63)
        else:
            self.reset_estimator()

    def reset_estimator(self) -> None:
        """The EKF starts again from its prior, the feedthrough cancellation from no
        history."""
        self.ekf.reset()
        self.canceller.reset()
        self._start_forced = False

    def process_pair(self, first: int, stamp_ns: int, y: np.ndarray, drive) -> None:
        """Cancel the feedthrough, run the EKF on one frame and publish theta, omega."""
        u, vb, fd = drive
        if self._start_forced:
            self.ekf.start_forced(u, fd)
            self._start_forced = False
        yc = self.canceller.step(y, vb, fd)
        x, v = self.ekf.step(yc, u, corrected=self.p["output_correction"])
        if self.ekf.diverged() or not state_ok(x, v):
            self.reset_estimator()
            raise Diverged("stage EKF")
        msg = output_frame(
            make_state_estimate,
            x,
            v,
            first=first,
            fs=self.model.fs,
            stamp_ns=stamp_ns,
            estimator="ekf",
            state_names=("theta", "omega"),
            state_units=("rad", "rad/s"),
            frame_id="stage",
        )
        self.pub.publish(msg)


def main(argv: list[str] | None = None) -> int:
    """Entry point ``stage_ekf_node``."""
    return run_node(StageEkfNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
