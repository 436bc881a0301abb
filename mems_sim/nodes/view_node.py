"""ROS 2 node of a device's plotting view (thin wrapper of :mod:`mems_sim.views`).

Started in a device's namespace (``view_node --ros-args -r __ns:=/stage``), it subscribes to
the device's frames and publishes, per channel, a low-rate stream that a plotter
(Foxglove, PlotJuggler) draws as a signal without aliasing:

    ``truth``, ``estimate``        inputs: mems_msgs/SignalFrame, mems_msgs/StateEstimate
    ``view/<input>/<channel>``     geometry_msgs/Vector3Stamped, one message per output point,
                                   ``header.stamp`` in the device's sensor time:
                                   carriers (per period): x = amplitude, y = phase [rad],
                                   z = offset (IEEE Std 1057 three-parameter sine fit);
                                   slow signals (decimated): x = anti-alias-filtered value,
                                   y = minimum, z = maximum of the samples of its interval
    ``/diagnostics``               views, frame-index gaps (a gap restarts the input's views)

Which channels are carriers and the output rate come from the device's row of
:data:`mems_sim.views.DEVICE_VIEWS` (``device`` 'auto': the namespace's last name), and can
be set with the parameters below.
"""

from __future__ import annotations

from functools import partial

import numpy as np
from geometry_msgs.msg import Vector3Stamped

from mems_msgs.msg import SignalFrame, StateEstimate
from mems_sim import views
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import (
    FrameError,
    estimate_states,
    index_to_ns,
    ns_to_time,
    signal_data,
    time_to_ns,
)
from mems_sim.ros.node_base import MemsNode
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_QOS

VIEW_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "device",
        "auto",
        "-",
        "row of the device view table (mems_sim.views.DEVICE_VIEWS); 'auto': the namespace's "
        "last name ('' row if not in the table)",
        "",
        choices=("auto", *sorted(k for k in views.DEVICE_VIEWS if k)),
    ),
    ParamSpec(
        "inputs",
        "truth,estimate",
        "-",
        "comma-separated input topics (relative): SignalFrame, or StateEstimate for names "
        "ending in 'estimate'",
        "",
    ),
    ParamSpec(
        "carrier_channels",
        "auto",
        "-",
        "comma-separated channels viewed per carrier period; 'auto': the device's row; "
        "'none': every channel decimated",
        "",
    ),
    ParamSpec(
        "carrier_hz",
        0.0,
        "Hz",
        "carrier frequency of the per-period views; 0: estimated per channel from the mean "
        "period between rising zero crossings of its first samples, then held",
        "IEEE Std 1057-2017 three-parameter sine fit (known frequency)",
        min=0.0,
        max=1.0e9,
    ),
    ParamSpec(
        "periods",
        1,
        "-",
        "carrier periods per output point of a per-period view",
        "",
        min=1,
        max=1_000_000,
    ),
    ParamSpec(
        "output_rate_hz",
        0.0,
        "Hz",
        "output rate of the decimated views (the decimation factor is the nearest whole "
        "ratio to the input rate); 0: the device's row",
        "scipy.signal.decimate (FIR anti-alias filter), here streaming with known delay",
        min=0.0,
        max=1.0e9,
    ),
)


def _names(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


class _InputViews:
    """The views of one input topic (built at its first frame, rebuilt after a gap)."""

    def __init__(self, node: ViewNode, topic: str, msg, names: list[str]) -> None:
        self.fs = float(msg.sample_rate_hz)
        self.names = names
        self.first = self.next_index = int(msg.first_sample_index)
        self.epoch_ns = time_to_ns(msg.header.stamp) - index_to_ns(msg.first_sample_index, self.fs)
        self.frame_id = msg.header.frame_id
        carriers = node.carriers
        self.fitters = {
            c: views.PeriodFitter(self.fs, node.p["carrier_hz"], node.p["periods"], self.first)
            for c, name in enumerate(names)
            if name in carriers
        }
        self.slow = [c for c in range(len(names)) if c not in self.fitters]
        q = max(1, round(self.fs / node.output_rate)) if node.output_rate > 0 else 1
        self.decimator = views.Decimator(q, len(self.slow)) if self.slow else None
        self.pubs = [node.view_publisher(f"view/{topic}/{name}") for name in names]

    def stamp(self, index: float):
        """Sensor time of a (fractional) sample index: epoch + index / fs."""
        whole = int(np.floor(index))
        ns = index_to_ns(whole, self.fs, self.epoch_ns)
        ns += int(round((index - whole) * 1e9 / self.fs))
        return ns_to_time(ns)

    def take(self, first: int, data: np.ndarray) -> None:
        for c, fitter in self.fitters.items():
            fit = fitter.push(data[:, c])
            for k in range(fit.index.size):
                self._publish(c, fit.index[k], fit.amplitude[k], fit.phase[k], fit.offset[k])
        if self.decimator is not None:
            idx, val, lo, hi = self.decimator.push(data[:, self.slow])
            for k in range(idx.size):  # the decimator counts from this view's first sample
                for j, c in enumerate(self.slow):
                    self._publish(c, self.first + idx[k], val[k, j], lo[k, j], hi[k, j])
        self.next_index = first + data.shape[0]

    def _publish(self, channel: int, index: float, x: float, y: float, z: float) -> None:
        msg = Vector3Stamped()
        msg.header.stamp = self.stamp(index)
        msg.header.frame_id = self.frame_id
        msg.vector.x, msg.vector.y, msg.vector.z = float(x), float(y), float(z)
        self.pubs[channel].publish(msg)


class ViewNode(MemsNode):
    """Plotting view of one device's truth and estimate frames (module docstring)."""

    NODE_NAME = "view"
    DEFAULT_NAMESPACE = ""
    SPECS = VIEW_SPECS
    DIAGNOSTICS_TITLE = "plotting view"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        device = self.p["device"]
        if device == "auto":
            device = self.get_namespace().rstrip("/").rsplit("/", 1)[-1]
        row = views.DEVICE_VIEWS.get(device, views.DEVICE_VIEWS[""])
        self.device = device
        spec = self.p["carrier_channels"]
        self.carriers = set(
            row["carriers"] if spec == "auto" else () if spec == "none" else _names(spec)
        )
        self.output_rate = self.p["output_rate_hz"] or row["output_rate_hz"]
        inputs = _names(self.p["inputs"])
        if not inputs:
            raise ParameterError("parameter 'inputs' = '' names no topic")
        self.views: dict[str, _InputViews | None] = {}
        self.subs = []
        for topic in inputs:
            kind = StateEstimate if topic.endswith("estimate") else SignalFrame
            self.views[topic] = None
            self.subs.append(
                # partial, not a lambda with a default: rclpy hands the message info to a
                # callback that takes a second argument
                self.create_subscription(kind, topic, partial(self.on_frame, topic), FRAME_QOS)
            )
        self.frames_received = 0
        self._view_pubs: dict[str, object] = {}

    def view_publisher(self, topic: str):
        """The publisher of one view topic (made once, kept across restarts)."""
        if topic not in self._view_pubs:
            self._view_pubs[topic] = self.create_publisher(Vector3Stamped, topic, FRAME_QOS)
        return self._view_pubs[topic]

    def on_frame(self, topic: str, msg) -> None:
        """Feed one frame to the input's views (built at the first frame; a gap or another
        sample rate restarts them)."""
        try:
            if isinstance(msg, StateEstimate):
                data, names = estimate_states(msg), list(msg.state_names)
            else:
                data, names = signal_data(msg), list(msg.channel_names)
        except FrameError as exc:
            self.diag.count(f"rejected_{exc.reason}")
            return
        v = self.views[topic]
        first = int(msg.first_sample_index)
        if v is not None and (
            first != v.next_index or msg.sample_rate_hz != v.fs or names != v.names
        ):
            self.diag.count("restarts")
            self.diag.warn(f"{topic}: frame at {first}, expected {v.next_index}: views restart")
            v = None
        if v is None:
            v = self.views[topic] = _InputViews(self, topic, msg, names)
        v.take(first, data)
        self.frames_received += 1
        self.diag.count("frames")


def main(argv: list[str] | None = None) -> int:
    """Entry point ``view_node`` (``ros2 run mems_emulator view_node``)."""
    return run_node(ViewNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
