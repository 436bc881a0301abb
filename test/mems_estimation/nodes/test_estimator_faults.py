"""Estimators that survive faulty input, through real topics.

For every estimator node, one seeded record of its device (the emulator node, stepped
here) is fed twice through real topics into a fresh estimator node: once as recorded and
once with faults inserted -- absurd but finite frames (the drive frame's first channel
scaled by 1e150, which makes every filter diverge; an ADC frame whose lsb is scaled by
1e12; for the calibration the stage estimate scaled by 1e150), a code outside the
declared bit range, an empty and a malformed (undecodable) frame, a stray frame of
another rate and channel set, a repeated pair, two pairs out of order, an index jump of
1e9 (a gap), a 1e7-sample frame, 3e7 samples of frames that never find their partner, and
last an index jump of 2^62 (beyond ``max_gap_samples``: a stream reset). The data after a
jump are the recorded samples; only their indices are shifted.

Checked per node: the node keeps running and takes every frame; every event is counted on
/diagnostics; the memory Python and numpy hold stays bounded (tracemalloc: the 1e7-sample
frame costs a few copies of that message, the 3e7 unpaired samples no more than the
pairing bound); ``~/progress`` ends one past the last sample of the stream; and over the
second of data after the last fault the estimates are finite and their RMS error against
the device's truth is at most 1.5 times that of the fault-free run over the same samples.
The last fault is a stream reset by a jump ahead, judged on the second right after it:
the accelerometer EKF, the resonator observer and the AMDM EKF/UKF start again from their
prior and are back within milliseconds; the stage EKF starts again at the forced steady
state under the drive, the threshold EKF continues as over a gap (from their prior both
would need 0.1-0.2 s: their angle is not measured directly, its error decays with the
mechanical damping; a stream that starts again, a device at rest, is their prior's case).
The gyro calibration and the noise
identification publish a result instead of a stream: the fault run's final result must be
close to the fault-free one (scale factor and bias within 3 standard errors; N, B and K
within 5 % or one standard error). The IMU identifier has one input stream, so there is
nothing to pair (no unpaired frames for it); the calibration's unpaired samples are
estimate frames and its out-of-range code is in the gyro's frames.
"""

from __future__ import annotations

import array
import math
import time
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticArray
from node_helpers import one_channel_adc
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import UInt64

from mems_estimation.nodes.accelerometer_ekf_node import AccelerometerEkfNode
from mems_estimation.nodes.frame_input import FormatPin
from mems_estimation.nodes.imu_noise_identifier_node import ImuNoiseIdentifierNode
from mems_estimation.nodes.resonator_observer_node import ResonatorObserverNode
from mems_estimation.nodes.scanner_amdm_estimator_node import ScannerAmdmEstimatorNode
from mems_estimation.nodes.scanner_threshold_ekf_node import ScannerThresholdEkfNode
from mems_estimation.nodes.stage_ekf_node import StageEkfNode
from mems_estimation.nodes.stage_gyro_calibration_node import StageGyroCalibrationNode
from mems_msgs.msg import AdcFrame, CalibrationResult, NoiseModel, SignalFrame, StateEstimate
from mems_sim.devices import accelerometer
from mems_sim.devices.scanner_amdm import SWEEP_STUDY
from mems_sim.nodes.accelerometer_node import AccelerometerNode
from mems_sim.nodes.imu_node import ImuNode
from mems_sim.nodes.resonator_node import ResonatorNode
from mems_sim.nodes.scanner_amdm_node import ScannerAmdmNode
from mems_sim.nodes.scanner_node import ScannerNode
from mems_sim.nodes.stage_node import StageNode
from mems_sim.ros.frames import (
    index_to_ns,
    make_signal_frame,
    make_state_estimate,
    ns_to_time,
    signal_data,
    time_to_ns,
)
from mems_sim.ros.node_base import FRAME_TYPES
from mems_sim.ros.qos import FRAME_QOS, PROGRESS_QOS, RESULT_QOS

REPO = Path(__file__).resolve().parents[3]
EPOCH_NS = 1_767_225_600 * 10**9  # 2026-01-01 UTC: the clean run's epoch
JUMP_GAP = 10**9  # below max_gap_samples (2^32): a gap
JUMP_RESET = 2**62  # beyond it: a stream reset
BIG = 10**7  # samples of the oversized frame
UNPAIRED = 3 * 10**7  # samples of frames without partner
UNPAIRED_FRAME = 250_000
FAR = 2**40  # index offset of the unpaired frames (never reached, never behind)
EVAL_S = 1.0
#: Publishers of the fault injector: reliable, shallow (the big messages are not kept).
INJECT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


# ---------------------------------------------------------------------- the cases


@dataclass
class Case:
    """One estimator node, its device and how its output is judged."""

    name: str
    device: type
    device_params: dict
    namespace: str
    estimator: type
    estimator_params: dict
    fs: float
    frame: int
    #: input streams (topics relative to the namespace): primary and paired secondary
    primary: str = "adc"
    secondary: str | None = "drive"
    #: output topic -> [(state name, truth channel)]; sign-free: the mirror image counts
    outputs: dict = field(default_factory=dict)
    sign_free: bool = False
    #: whether the absurd drive frame makes the filter diverge (counted)
    diverges: bool = True
    warm_frames: int = 10
    #: normal frames after the absurd frames (the calibration lets their trial complete)
    after_absurd: int = 1
    #: record length [s] if not the faults plus the judged second (a result node)
    record_s: float | None = None

    def duration_s(self) -> float:
        if self.record_s is not None:
            return self.record_s
        eval_frames = math.ceil(EVAL_S * self.fs / self.frame)
        return (self.warm_frames + self.after_absurd + 24 + eval_frames) * self.frame / self.fs


G0 = 9.80665
STAGE_YAML = str(REPO / "bags" / "stage_params.yaml")
CASES = {
    c.name: c
    for c in (
        Case(
            "accelerometer_ekf",
            AccelerometerNode,
            dict(seed=3, mode="pi_rebalance", accel_amplitude=0.5 * G0),
            "/accelerometer",
            AccelerometerEkfNode,
            dict(mode="pi_rebalance"),
            1e6,
            10_000,
            outputs={
                "estimate": [
                    ("displacement", "displacement"),
                    ("velocity", "velocity"),
                    ("acceleration", "acceleration"),
                ]
            },
        ),
        Case(
            "stage_ekf",
            StageNode,
            dict(seed=3, n_trials=8, periods_per_trial=400, gyro_enabled=False),
            "/stage",
            StageEkfNode,
            dict(params_yaml=STAGE_YAML),
            625e3,
            10_000,
            outputs={"estimate": [("theta", "theta_y"), ("omega", "omega_y")]},
        ),
        Case(
            "stage_gyro_calibration",
            StageNode,
            dict(seed=5, n_trials=14, periods_per_trial=100),
            "/stage",
            StageGyroCalibrationNode,
            dict(n_trials=7),
            625e3,
            10_000,
            primary="estimate",
            diverges=False,
            warm_frames=4,
            after_absurd=10,
        ),
        Case(
            "scanner_threshold_ekf",
            ScannerNode,
            dict(seed=4, sweep_time_s=0.05, hold_time_s=5.0, ringdown_time_s=0.0),
            "/scanner",
            ScannerThresholdEkfNode,
            {},
            500e3,
            10_000,
            outputs={
                "estimate": [("theta", "theta"), ("omega", "omega")],
                "estimate_plain": [("theta", "theta"), ("omega", "omega")],
            },
        ),
        Case(
            "scanner_amdm_estimator",
            ScannerAmdmNode,
            dict(SWEEP_STUDY, seed=15),
            "/scanner_amdm",
            ScannerAmdmEstimatorNode,
            {},
            1e6,
            10_000,
            outputs={
                "ekf/estimate": [("theta", "theta"), ("omega", "omega")],
                "ukf/estimate": [("theta", "theta"), ("omega", "omega")],
            },
            sign_free=True,
        ),
        Case(
            "resonator_observer",
            ResonatorNode,
            dict(seed=5, mode="observer", output_noise_std=0.5, state_noise_std=5e-4),
            "/resonator",
            ResonatorObserverNode,
            dict(output_noise_std=0.5, state_noise_std=5e-4),
            1e6,
            10_000,
            outputs={"estimate": [("position", "position")]},
        ),
        Case(
            "imu_noise_identifier",
            ImuNode,
            dict(seed=11, publish_imu=False),
            "/imu",
            ImuNoiseIdentifierNode,
            dict(publish_period_s=0.0),
            100.0,
            100,
            secondary=None,
            diverges=False,
            record_s=600.0,
        ),
    )
}


# ---------------------------------------------------------------------- messages


def ints(values) -> array.array:
    """An int32[] field value (array.array: rclpy takes it without checking each value)."""
    out = array.array("i")
    out.frombytes(np.ascontiguousarray(values, dtype=np.int32).tobytes())
    return out


def floats(values) -> array.array:
    """A float64[] field value."""
    out = array.array("d")
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


def clone(msg, **fields):
    """A copy of a frame message with some fields replaced."""
    out = type(msg)()
    for name in msg.get_fields_and_field_types():
        setattr(out, name, fields[name] if name in fields else getattr(msg, name))
    return out


def shifted(msg, offset: int):
    """The frame with its first sample index moved by ``offset`` (same stamp and data)."""
    return msg if offset == 0 else clone(msg, first_sample_index=msg.first_sample_index + offset)


def restamped(msg, epoch_ns: int):
    """The frame with its header stamp moved by ``epoch_ns`` (another run's epoch)."""
    if epoch_ns == 0:
        return msg
    header = type(msg.header)()
    header.frame_id = msg.header.frame_id
    header.stamp = ns_to_time(time_to_ns(msg.header.stamp) + epoch_ns)
    return clone(msg, header=header)


def payload_field(msg) -> str:
    return {AdcFrame: "codes", StateEstimate: "states"}.get(type(msg), "data")


def scaled(msg, factor: float):
    """Absurd but finite: the first channel of a SignalFrame or every state of a
    StateEstimate times ``factor`` (an AdcFrame: its lsb and offset times ``factor``)."""
    if isinstance(msg, AdcFrame):
        return clone(
            msg,
            lsb=[v * factor for v in msg.lsb],
            offset=[v * factor for v in msg.offset],
        )
    name = payload_field(msg)
    k = len(msg.state_names if isinstance(msg, StateEstimate) else msg.channel_names)
    values = np.array(getattr(msg, name), dtype=float).reshape(-1, k)
    if isinstance(msg, StateEstimate):
        values *= factor  # every state (theta and omega)
    else:
        values[:, 0] *= factor  # the first channel (drive voltage, pulse height)
    return clone(msg, **{name: floats(values)})


def out_of_range(msg):
    """An AdcFrame with one code 7 beyond the declared bit range."""
    codes = np.array(msg.codes, dtype=np.int32)
    codes[len(codes) // 2] = (2 ** (msg.bits - 1) if msg.bits > 1 else 1) + 7
    return clone(msg, codes=ints(codes))


def empty(msg):
    """No samples, no payload."""
    name = payload_field(msg)
    return clone(msg, num_samples=0, **{name: ints([]) if name == "codes" else floats([])})


def malformed(msg):
    """A payload one value short of num_samples x channels (undecodable)."""
    name = payload_field(msg)
    return clone(msg, **{name: getattr(msg, name)[:-1]})


def foreign(msg):
    """A stray frame of another device: twice the rate, another channel set."""
    fields = {"sample_rate_hz": 2.0 * msg.sample_rate_hz}
    if isinstance(msg, StateEstimate):
        fields["state_names"] = [f"other_{n}" for n in msg.state_names]
    else:
        fields["channel_names"] = [f"other_{n}" for n in msg.channel_names]
    return clone(msg, **fields)


def one_channel_frame(msg, first: int, n: int):
    """A frame of n samples at ``first`` in (the first channel of) ``msg``'s format."""
    if isinstance(msg, AdcFrame):
        return clone(
            msg,
            first_sample_index=first,
            num_samples=n,
            channel_names=list(msg.channel_names)[:1],
            channel_units=list(msg.channel_units)[:1],
            lsb=list(msg.lsb)[:1],
            offset=list(msg.offset)[:1],
            full_scale=list(msg.full_scale)[:1],
            codes=ints(np.zeros(n)),
        )
    if isinstance(msg, StateEstimate):
        return clone(
            msg,
            first_sample_index=first,
            num_samples=n,
            state_names=list(msg.state_names)[:1],
            state_units=list(msg.state_units)[:1],
            states=floats(np.zeros(n)),
            variances=floats(np.ones(n)),
        )
    return clone(
        msg,
        first_sample_index=first,
        num_samples=n,
        channel_names=list(msg.channel_names)[:1],
        channel_units=list(msg.channel_units)[:1],
        data=floats(np.zeros(n)),
    )


def same_format_frame(msg, first: int, n: int):
    """A frame of n samples at ``first`` in ``msg``'s own format (every channel)."""
    if isinstance(msg, AdcFrame):
        k = len(msg.channel_names)
        code = 1 if msg.bits == 1 else 0  # a valid code (one-bit streams: -1/+1)
        return clone(msg, first_sample_index=first, num_samples=n, codes=ints(np.full(n * k, code)))
    if isinstance(msg, StateEstimate):
        k = len(msg.state_names)
        return clone(
            msg,
            first_sample_index=first,
            num_samples=n,
            states=floats(np.zeros(n * k)),
            variances=floats(np.ones(n * k)),
        )
    k = len(msg.channel_names)
    return clone(msg, first_sample_index=first, num_samples=n, data=floats(np.zeros(n * k)))


# ---------------------------------------------------------------------- memory


class Memory:
    """Peak of the memory Python and numpy hold (tracemalloc: the node's frames, decoded
    values and buffers, the test's messages) over (nested) phases, above the amount held
    at each phase's start [MB]."""

    def __init__(self) -> None:
        self.peaks: dict[str, float] = {}
        self.big_mb = 0.0
        self._open: dict[str, list[int]] = {}

    def _update(self) -> None:
        peak = tracemalloc.get_traced_memory()[1]
        for entry in self._open.values():
            entry[1] = max(entry[1], peak)

    def start(self, name: str) -> None:
        if not tracemalloc.is_tracing():
            tracemalloc.start()
        self._update()
        tracemalloc.reset_peak()
        now = tracemalloc.get_traced_memory()[0]
        self._open[name] = [now, now]

    def stop(self, name: str) -> None:
        self._update()
        base, peak = self._open.pop(name)
        self.peaks[name] = round((peak - base) / 2**20, 1)
        if not self._open:
            tracemalloc.stop()


def payload_mb(msg) -> float:
    """Size of a frame's sample arrays [MB]."""
    names = ("codes", "data", "states", "variances")
    return (
        sum(len(getattr(msg, n)) * (4 if n == "codes" else 8) for n in names if hasattr(msg, n))
        / 2**20
    )


# ---------------------------------------------------------------------- graph helpers


def capture(ex, probe, case: Case) -> dict[str, list]:
    """Run the case's device for its duration; its frames per topic, as published."""
    topics = ["adc", "truth"] + (["drive"] if case.secondary else [])
    if case.name == "stage_gyro_calibration":
        topics.append("gyro/adc")
    dev = case.device(
        context=probe.context,
        drive_externally=True,
        namespace=case.namespace,
        parameter_overrides=params(
            **case.device_params, frame_size=case.frame, duration_s=case.duration_s()
        ),
    )
    ex.add_node(dev)
    got = {t: [] for t in topics}
    subs = [
        probe.create_subscription(
            FRAME_TYPES.get(t.rsplit("/", 1)[-1], SignalFrame),
            f"{case.namespace}/{t}",
            got[t].append,
            FRAME_QOS,
        )
        for t in topics
    ]
    names = {f"{case.namespace}/{t}" for t in topics}
    assert spin_until(
        ex,
        lambda: all(
            p.get_subscription_count() >= 1 for p in dev.publishers if p.topic_name in names
        ),
    )
    steps = 0
    while dev.step():
        steps += 1
        if steps % 20 == 0:
            assert spin_until(ex, lambda: len(got["adc"]) >= steps - 10, timeout=30)
    assert spin_until(ex, lambda: all(len(got[t]) >= steps for t in ("adc", "truth")), timeout=30)
    spin_until(ex, lambda: False, timeout=0.2)  # the last gyro frames
    for sub in subs:  # the injected frames must not land in the record
        probe.destroy_subscription(sub)
    ex.remove_node(dev)
    dev.destroy_node()
    if case.name == "stage_gyro_calibration":
        got["estimate"] = [truth_estimate(m) for m in got["truth"]]
    return got


def truth_estimate(truth: SignalFrame) -> StateEstimate:
    """A stage estimate equal to the truth (theta_y, omega_y): the calibration's input."""
    d = signal_data(truth)
    names = list(truth.channel_names)
    x = d[:, [names.index("theta_y"), names.index("omega_y")]]
    msg = make_state_estimate(
        x,
        np.full_like(x, 1e-12),
        truth.first_sample_index,
        truth.sample_rate_hz,
        estimator="ekf",
        state_names=("theta", "omega"),
        state_units=("rad", "rad/s"),
        frame_id="stage",
    )
    msg.header.stamp = truth.header.stamp
    return msg


def counters(node) -> dict:
    c = dict(node.diag.counters)
    c["done"] = node.frames_done + int(c.get("divergences", 0))
    if isinstance(node, ImuNoiseIdentifierNode):
        c["done"] = int(c.get("frames", 0))
    return c


class Feeder:
    """Publishes a record into an estimator node step by step, each step waiting for the
    node's counters to show what it did with it."""

    def __init__(self, ex, probe, node, case: Case, record: dict) -> None:
        self.ex, self.node, self.case, self.rec = ex, node, case, record
        ns = case.namespace
        self.pubs = {
            t: probe.create_publisher(type(record[t][0]), f"{ns}/{t}", INJECT_QOS)
            for t in (case.primary, case.secondary, "gyro/adc")
            if t and t in record
        }
        assert spin_until(
            ex, lambda: all(p.get_subscription_count() >= 1 for p in self.pubs.values())
        )
        self.gyro = list(record.get("gyro/adc", []))
        self.gyro_sent = 0
        #: added to every stamp published (the clean run: a wall-clock-like epoch)
        self.epoch_ns = 0
        self.streams = 2 if case.secondary else 1

    def publish(self, topic: str, msg) -> None:
        self.pubs[topic].publish(restamped(msg, self.epoch_ns))

    def wait(self, key: str, delta: int, base: dict, timeout: float = 60.0) -> None:
        target = int(base.get(key, 0)) + delta
        ok = spin_until(self.ex, lambda: int(counters(self.node).get(key, 0)) >= target, timeout)
        assert ok, (self.case.name, key, counters(self.node).get(key, 0), target)

    def frames(self, k: int, offset: int, primary=None, secondary=None) -> None:
        """Publish record frame k (shifted by ``offset``), optionally replaced."""
        c = self.case
        self.publish(c.primary, primary or shifted(self.rec[c.primary][k], offset))
        if c.secondary:
            self.publish(c.secondary, secondary or shifted(self.rec[c.secondary][k], offset))
        self.gyro_until(k)

    def gyro_until(self, k: int) -> None:
        """Publish the gyro frames stamped before the end of stage frame k."""
        if not self.gyro:
            return
        end = time_to_ns(self.rec["truth"][k].header.stamp) + int(
            1e9 * self.case.frame / self.case.fs
        )
        while (
            self.gyro_sent < len(self.gyro)
            and time_to_ns(self.gyro[self.gyro_sent].header.stamp) < end
        ):
            self.publish("gyro/adc", self.gyro[self.gyro_sent])
            self.gyro_sent += 1

    def normal(self, ks, offset: int, batch: int = 5) -> None:
        ks = list(ks)
        for i in range(0, len(ks), batch):
            base = counters(self.node)
            for k in ks[i : i + batch]:
                self.frames(k, offset)
            self.wait("done", len(ks[i : i + batch]), base)


def run_clean(ex, feeder: Feeder, n: int) -> None:
    """The record as it is, its stamps on a wall-clock-like epoch (:data:`EPOCH_NS`)."""
    feeder.epoch_ns = EPOCH_NS
    feeder.normal(range(n), 0)


def check_timeline(msgs: list, topic: str) -> None:
    """Every estimate is stamped on its input's timeline: EPOCH_NS + first / fs, up to one
    constant per topic (a documented delay, e.g. the AMDM chain's) below 1 ms."""
    offsets = {
        time_to_ns(m.header.stamp) - EPOCH_NS - index_to_ns(m.first_sample_index, m.sample_rate_hz)
        for m in msgs
    }
    assert len(offsets) == 1 and abs(min(offsets)) < 10**6, (topic, sorted(offsets)[:5])


def run_faults(ex, feeder: Feeder, n: int, mem: Memory) -> tuple[int, int]:
    """The fault sequence (module doc); returns (record frame where the last fault's data
    start, index offset after it)."""
    c, f, rec = feeder.case, feeder, feeder.rec
    P, S = c.primary, c.secondary
    node = feeder.node
    k = c.warm_frames
    f.normal(range(k), 0)
    off = 0

    def step(key, delta, publish):
        base = counters(node)
        publish()
        f.wait(key, delta, base)

    # absurd but finite frames
    if S:
        step("done", 1, lambda: f.frames(k, off, secondary=scaled(rec[S][k], 1e150)))
        k += 1
    if isinstance(rec[P][0], AdcFrame):
        step("rejected_foreign", 1, lambda: f.frames(k, off, primary=scaled(rec[P][k], 1e12)))
    else:
        step("done", 1, lambda: f.frames(k, off, primary=scaled(rec[P][k], 1e150)))
    k += 1
    f.normal(range(k, k + c.after_absurd), off)
    k += c.after_absurd
    # a code outside the declared bit range
    if isinstance(rec[P][0], AdcFrame):
        step("rejected_out_of_range", 1, lambda: f.frames(k, off, primary=out_of_range(rec[P][k])))
    else:  # the calibration's ADC input is the gyro's
        j = max(f.gyro_sent - 1, 0)
        step("rejected_out_of_range", 1, lambda: f.publish("gyro/adc", out_of_range(f.gyro[j])))
        step("done", 1, lambda: f.frames(k, off))
    k += 1
    f.normal([k], off)
    k += 1
    # empty and malformed payloads, a stray frame of another rate and channel set: each
    # at the next index, before the genuine frame
    step("rejected_empty", 1, lambda: f.publish(P, empty(shifted(rec[P][k], off))))
    step("rejected_malformed", 1, lambda: f.publish(P, malformed(shifted(rec[P][k], off))))
    step("rejected_foreign", 1, lambda: f.publish(P, foreign(shifted(rec[P][k], off))))
    f.normal([k], off)
    # the same frame(s) again
    step("repeated_frames", f.streams, lambda: f.frames(k, off))
    k += 1
    # two frames out of order: k + 1 is taken (a gap), k then dropped
    step("done", 1, lambda: f.frames(k + 1, off))
    step("out_of_order_frames", f.streams, lambda: f.frames(k, off))
    k += 2
    f.normal([k], off)
    k += 1
    # an index jump of 1e9 samples: a gap
    off += JUMP_GAP
    step("gaps", 1, lambda: f.frames(k, off))
    k += 1
    f.normal([k], off)
    k += 1
    # a frame of 1e7 samples (the first channel of the stream's format)
    big = one_channel_frame(rec[P][k], rec[P][k].first_sample_index + off, BIG)
    mem.big_mb = payload_mb(big)
    mem.start("big_frame")
    step("rejected_oversized", 1, lambda: f.publish(P, big))
    mem.stop("big_frame")
    big = None
    f.normal([k], off)
    k += 1
    # 3e7 samples of frames whose partner never comes (far ahead: never reached)
    if S:
        mem.start("unpaired")
        template = rec[P][k]
        # what the pairing may hold (decoded float64 values), plus one frame in flight: its
        # message (built here, sent, received) and its decoded values (with their copies)
        width = len(getattr(template, "channel_names", [])) or 1
        message_mb = payload_mb(same_format_frame(template, 0, UNPAIRED_FRAME))
        decoded_mb = UNPAIRED_FRAME * width * 8 / 2**20
        held_mb = node.p["max_unpaired_samples"] * width * 8 / 2**20
        mem.unpaired_bound_mb = held_mb + 3 * decoded_mb + 3 * message_mb
        nframes = UNPAIRED // UNPAIRED_FRAME
        for j in range(nframes):
            first = template.first_sample_index + off + FAR + j * UNPAIRED_FRAME
            f.publish(P, same_format_frame(template, first, UNPAIRED_FRAME))

            def taken(j=j):
                held = len(node.pairer.frames[P])
                return held + int(node.diag.counters.get("unpaired_overflow_frames", 0)) >= j + 1

            assert spin_until(ex, taken, timeout=30)
        assert node.pairer.samples[P] <= node.p["max_unpaired_samples"]
        mem.stop("unpaired")
        f.normal([k], off)
        k += 1
    # an index jump of 2^62 samples: beyond max_gap_samples, a stream reset (last fault)
    off += JUMP_RESET
    step("stream_resets", 1, lambda: f.frames(k, off))
    last = k
    k += 1
    f.normal(range(k, n), off)
    return last, off


# ---------------------------------------------------------------------- judging


def estimates(msgs: list, names: list[str], offset: int, lo: int, hi: int) -> np.ndarray:
    """States ``names`` of record samples [lo, hi) from estimate messages whose indices are
    the record's plus ``offset`` (NaN where none)."""
    out = np.full((hi - lo, len(names)), np.nan)
    for m in msgs:
        first = int(m.first_sample_index) - offset
        if first + m.num_samples <= lo or first >= hi or first < 0:
            continue
        k = len(m.state_names)
        s = np.asarray(m.states).reshape(-1, k)[:, [list(m.state_names).index(n) for n in names]]
        a, b = max(first, lo), min(first + m.num_samples, hi)
        out[a - lo : b - lo] = s[a - first : b - first]
    return out


def truth_of(record: dict, channels: list[str], lo: int, hi: int) -> np.ndarray:
    d = np.concatenate([signal_data(m) for m in record["truth"]])
    names = list(record["truth"][0].channel_names)
    return d[lo:hi][:, [names.index(c) for c in channels]]


def rms_error(est: np.ndarray, truth: np.ndarray, sign_free: bool) -> np.ndarray:
    e = np.sqrt(np.mean((est - truth) ** 2, axis=0))
    if sign_free:
        e = np.minimum(e, np.sqrt(np.mean((est + truth) ** 2, axis=0)))
    return e


def last_status(diags: list, prefix: str) -> dict:
    found = [s for d in diags for s in d.status if s.name.startswith(prefix)]
    return {kv.key: kv.value for kv in found[-1].values} if found else {}


def build_estimator(ctx, case: Case, name: str):
    return case.estimator(
        context=ctx,
        namespace=case.namespace,
        parameter_overrides=params(**case.estimator_params),
    )


@pytest.mark.parametrize("name", list(CASES))
def test_estimator_survives_faults(name, graph):
    ctx, ex, probe = graph
    case = CASES[name]
    t_start = time.monotonic()
    record = capture(ex, probe, case)
    n = len(record[case.primary])
    if case.secondary:
        n = min(n, len(record[case.secondary]))
    outputs = {}
    diags: list = []
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 50)
    mem = Memory()
    for run in ("clean", "faults"):
        node = build_estimator(ctx, case, run)
        ex.add_node(node)
        got = {t: [] for t in case.outputs}
        subs = [
            probe.create_subscription(
                StateEstimate, f"{case.namespace}/{t}", got[t].append, FRAME_QOS
            )
            for t in case.outputs
        ]
        results = []
        result_topic = {
            "stage_gyro_calibration": (CalibrationResult, "gyro_scale_factor"),
            "imu_noise_identifier": (NoiseModel, "noise_model"),
        }.get(case.name)
        if result_topic:
            subs.append(
                probe.create_subscription(
                    result_topic[0],
                    f"{case.namespace}/{result_topic[1]}",
                    results.append,
                    RESULT_QOS,
                )
            )
        progress = []
        subs.append(
            probe.create_subscription(
                UInt64, f"{node.get_fully_qualified_name()}/progress", progress.append, PROGRESS_QOS
            )
        )
        watched = {f"{case.namespace}/{t}" for t in case.outputs}
        if result_topic:
            watched.add(f"{case.namespace}/{result_topic[1]}")
        assert spin_until(
            ex,
            lambda: all(
                p.get_subscription_count() >= 1 for p in node.publishers if p.topic_name in watched
            ),
        )
        feeder = Feeder(ex, probe, node, case, record)
        if run == "clean":
            run_clean(ex, feeder, n)
            last, off = n, 0
        else:
            last, off = run_faults(ex, feeder, n, mem)
        close = getattr(node, "close", None)
        if close is not None:
            close()
        end = record[case.primary][n - 1]
        end_index = end.first_sample_index + end.num_samples + off
        assert spin_until(ex, lambda: progress and progress[-1].data == end_index, timeout=10), (
            progress[-1].data if progress else None,
            end_index,
        )
        if result_topic:  # every result the node published, the final one last
            assert spin_until(ex, lambda: len(results) >= len(node.results), 30)
            assert len(node.results) >= 1
        title = node.diag.status().name
        diags.clear()
        node.diag.publish()
        assert spin_until(ex, lambda: last_status(diags, title).get("frames") is not None, 10)
        if run == "clean":
            for topic, msgs in got.items():
                check_timeline(msgs, topic)
        outputs[run] = dict(got=got, results=list(results), last=last, off=off)
        outputs[run]["status"] = last_status(diags, title)
        outputs[run]["counters"] = dict(node.diag.counters)
        for sub in subs:
            probe.destroy_subscription(sub)
        for pub in feeder.pubs.values():
            probe.destroy_publisher(pub)
        ex.remove_node(node)
        node.destroy_node()

    # every event counted on /diagnostics
    s = outputs["faults"]["status"]
    clean = outputs["clean"]["status"]
    assert int(clean.get("rejected_frames", 0)) == 0 and int(clean.get("divergences", 0)) == 0
    expect = {
        "rejected_out_of_range": 1,
        "rejected_empty": 1,
        "rejected_malformed": 1,
        "rejected_oversized": 1,
        "repeated_frames": 2 if case.secondary else 1,
        "out_of_order_frames": 2 if case.secondary else 1,
        "stream_resets": 1,
    }
    for key, value in expect.items():
        assert int(s.get(key, 0)) == value, (key, s)
    foreign_frames = 1 if case.primary == "estimate" else 2
    assert int(s.get("rejected_foreign", 0)) == foreign_frames, s
    assert int(s.get("gaps", 0)) >= 2 and int(s.get("missing_samples", 0)) >= JUMP_GAP, s
    if case.secondary:
        assert int(s.get("unpaired_overflow_frames", 0)) >= 100, s
        assert int(s.get("unpaired_stale_frames", 0)) >= 1, s
    if case.diverges:
        assert int(s.get("divergences", 0)) >= 1, s
    if case.name == "stage_gyro_calibration":
        assert int(s.get("implausible_pairs", 0)) >= 1 and int(s.get("trials_dropped", 0)) >= 1, s

    # bounded memory: the big frame and the unpaired frames cost a few copies of a message
    print(f"\n{name}: {time.monotonic() - t_start:.1f} s, peak memory [MB] {mem.peaks}")
    assert mem.peaks["big_frame"] < 3 * mem.big_mb + 20, mem.peaks
    if case.secondary:  # unbounded, 3e7 samples would be 229 MB per channel
        assert mem.peaks["unpaired"] < mem.unpaired_bound_mb + 10, mem.peaks

    if case.name == "stage_gyro_calibration":
        a, b = outputs["clean"]["results"][-1], outputs["faults"]["results"][-1]
        print(
            f"scale factor clean {a.values[0]:.6f} +- {a.standard_errors[0]:.1e}, "
            f"faults {b.values[0]:.6f} +- {b.standard_errors[0]:.1e} ({b.num_points} pairs)"
        )
        assert b.num_points >= 7
        assert abs(b.values[0] - a.values[0]) < 3 * max(a.standard_errors[0], b.standard_errors[0])
        assert abs(b.values[1] - a.values[1]) < 3 * max(a.standard_errors[1], b.standard_errors[1])
        return
    if case.name == "imu_noise_identifier":
        a, b = outputs["clean"]["results"][-1], outputs["faults"]["results"][-1]
        assert a.final and b.final and b.num_samples >= a.num_samples - 500
        for x, y in zip(a.axes, b.axes):
            for term in ("white_noise_density", "bias_instability", "random_walk"):
                u, v = getattr(x, term), getattr(y, term)
                print(f"{x.axis} {term}: clean {u.value:.4g}, faults {v.value:.4g}")
                assert abs(v.value - u.value) <= max(0.05 * abs(u.value), u.standard_error), (
                    x.axis,
                    term,
                )
        return

    # the second of data after the last fault: finite, RMS error within 1.5x
    lo = outputs["faults"]["last"] * case.frame
    hi = lo + int(EVAL_S * case.fs)
    assert hi <= n * case.frame
    for topic, pairs in case.outputs.items():
        names, channels = [p[0] for p in pairs], [p[1] for p in pairs]
        truth = truth_of(record, channels, lo, hi)
        e_clean = estimates(outputs["clean"]["got"][topic], names, 0, lo, hi)
        e_fault = estimates(
            outputs["faults"]["got"][topic], names, outputs["faults"]["off"], lo, hi
        )
        have = np.all(np.isfinite(e_clean), axis=1)
        assert have.mean() > 0.99
        assert np.all(np.isfinite(e_fault[have])), f"{topic}: non-finite or missing estimates"
        r_clean = rms_error(e_clean[have], truth[have], case.sign_free)
        r_fault = rms_error(e_fault[have], truth[have], case.sign_free)
        print(f"{topic}: RMS error clean {r_clean}, faults {r_fault}")
        assert np.all(r_fault <= 1.5 * r_clean), (topic, r_clean, r_fault)


# ---------------------------------------------------------------------- progress


def _acc_frames(first: int, n: int = 1000):
    d = accelerometer.ForceRebalanceAccelerometer({"mode": "pi_rebalance"}, seed=1)
    codes = np.zeros(n, dtype=np.int32)
    adc = one_channel_adc(first, codes, 1e6, bits=16, name="readout", lsb=d.lsb, full_scale=0.5)
    drive = make_signal_frame(
        np.zeros((n, 2)),
        first,
        1e6,
        channel_names=("feedback_voltage", "bias_voltage"),
        channel_units=("V", "V"),
    )
    return adc, drive


def test_progress_reports_the_end_of_every_frame_taken(graph):
    """``~/progress``: std_msgs/UInt64, reliable and transient local; one past the last
    sample index of the primary input the node has finished with -- processed, rejected or
    dropped --; a late subscriber gets the last value; after a stream reset it follows the
    new stream."""
    ctx, ex, probe = graph
    node = AccelerometerEkfNode(context=ctx, parameter_overrides=params(mode="pi_rebalance"))
    ex.add_node(node)
    topic = "/accelerometer/accelerometer_ekf/progress"
    assert node.get_fully_qualified_name() + "/progress" == topic
    pub_a = probe.create_publisher(AdcFrame, "/accelerometer/adc", INJECT_QOS)
    pub_d = probe.create_publisher(SignalFrame, "/accelerometer/drive", INJECT_QOS)
    got = []
    probe.create_subscription(UInt64, topic, got.append, PROGRESS_QOS)
    assert spin_until(
        ex,
        lambda: (
            pub_a.get_subscription_count() == 1
            and node.progress_reporter.publisher.get_subscription_count()
        ),
    )
    (info,) = probe.get_publishers_info_by_topic(topic)
    assert info.topic_type == "std_msgs/msg/UInt64"
    assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    assert info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL

    def send(adc, drive=None, value=None):
        n = len(got)
        pub_a.publish(adc)
        if drive is not None:
            pub_d.publish(drive)
        assert spin_until(ex, lambda: len(got) > n)
        if value is not None:
            assert got[-1].data == value, (got[-1].data, value)

    send(*_acc_frames(0), value=1000)  # processed
    adc, drive = _acc_frames(1000)
    send(out_of_range(adc), value=2000)  # rejected
    send(*_acc_frames(2000), value=3000)  # processed after a gap
    send(*_acc_frames(2000), value=3000)  # repeated: dropped, progress unchanged
    big = _acc_frames(2**62)
    send(*big, value=2**62 + 1000)  # stream reset: follows
    assert node.frames_done == 3 and node.diag.counters["stream_resets"] == 1
    late = []
    probe.create_subscription(UInt64, topic, late.append, PROGRESS_QOS)
    assert spin_until(ex, lambda: late and late[-1].data == 2**62 + 1000)


def _imu_frame(first: int, n: int = 100, fs: float = 100.0, name: str = "gyro_x"):
    m = AdcFrame(
        first_sample_index=first,
        sample_rate_hz=fs,
        num_samples=n,
        bits=14,
        channel_names=[name],
        channel_units=["rad/s"],
    )
    m.lsb, m.offset, m.full_scale = (floats([v]) for v in (1e-3, 0.0, 8.192))
    m.codes = ints(np.random.default_rng(first).normal(0, 50, n))
    return m


def test_identifier_is_not_locked_out_by_a_stray_first_frame(graph):
    """A stray frame of another rate and channel set as the very first frame: the node
    takes its format, then the stream's own frames replace it after
    ``FormatPin.ADOPT_FRAMES`` frames (the stray frame's data are dropped with it)."""
    ctx, ex, probe = graph
    node = ImuNoiseIdentifierNode(context=ctx, parameter_overrides=params(min_duration_s=5.0))
    ex.add_node(node)
    pub = probe.create_publisher(AdcFrame, "/imu/adc", INJECT_QOS)
    assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
    frames = [_imu_frame(0, fs=200.0, name="other")] + [_imu_frame(100 * k) for k in range(20)]
    for m in frames:
        pub.publish(m)
    assert spin_until(ex, lambda: node.frames_received == len(frames))
    c = node.diag.counters
    assert c["format_changes"] == 1 and c["rejected_foreign"] == FormatPin.ADOPT_FRAMES - 1
    assert node.acc.fs == 100.0 and node.acc.channels == ("gyro_x",)
    assert node.acc.num_samples == 100 * (20 - FormatPin.ADOPT_FRAMES + 1)
