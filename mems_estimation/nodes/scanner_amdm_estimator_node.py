"""ROS 2 node: EKF and UKF of the shared-electrode micro-scanner on its AMDM output (Chen 2018 ch. 5).

Thin wrapper of :mod:`mems_estimation.filters.scanner_amdm_tracking`.  Subscribes ``<device>/adc``
(AdcFrame, channel ``y_cap`` [V]) and ``<device>/drive`` (SignalFrame, channel ``v_drive`` [V]),
pairs the frames by ``first_sample_index`` and runs both filters on every pair.

Publishes (``<device>/`` = ``device_namespace``, or nothing: relative names in the node's
namespace, default ``/scanner_amdm``):
    ``<device>/ekf/estimate``, ``<device>/ukf/estimate``  mems_msgs/StateEstimate
        theta [rad], omega [rad/s] with variances, one per AMDM sample; sample k describes
        t_k - chain_delay_s (the header stamp is shifted accordingly; first_sample_index is
        the AMDM index).  Before motion is acquired the states are 0 with the initial variances.
    ``<device>/ekf/phase_amplitude``, ``<device>/ukf/phase_amplitude``  mems_msgs/StateEstimate
        one entry per extremum of theta: t_peak [s], phase [rad] (time from the previous drive
        peak, as a fraction of the motion period, in [0, pi)), amplitude [rad] (|theta| at the
        extremum), with variances from the filter covariance; first_sample_index counts the
        extrema, sample_rate_hz = twice the model's natural frequency (nominal rate).
    ``/diagnostics``  frames, rejected frames, gaps, AC SNR, tracking state, PD failures;
        WARN "low signal" while no motion is observable (drive far from parametric resonance).
With ``output_namespace`` the four topics go to that namespace instead (an oracle filter
beside the device's own, e.g. ``/scanner_amdm/oracle/ekf/estimate``).
A frame at another sample rate, without the expected channel, with non-finite values or of
another length than its partner is rejected and counted (input path:
:class:`EstimatorNode`); a gap or a stream reset starts both filters again (re-acquire),
and so does a divergence of either (non-finite state or covariance not positive definite;
counted ``divergences``, that frame's estimates not published).
"""

from __future__ import annotations

import math

import numpy as np

from mems_estimation.filters import scanner_amdm_model as sam
from mems_estimation.filters import scanner_amdm_tracking as su
from mems_estimation.identification.scanner_amdm_identification import load_identification
from mems_estimation.nodes.frame_input import (
    DEVICE_NAMESPACE,
    Diverged,
    EstimatorNode,
    input_specs,
    output_frame,
)
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.kernels.divergence import state_ok
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import (
    FrameError,
    adc_physical,
    index_to_ns,
    make_state_estimate,
    signal_data,
)
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_QOS

NODE_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec("frame_id", "scanner", "-", "frame_id of the published estimates", ""),
    ParamSpec(
        "params_yaml",
        "",
        "-",
        "identified model YAML (scanner_amdm_identification): its inertia, spring_constant "
        "and damping replace the parameters' (empty: the parameters as given, by default "
        "the nominal device's: the oracle model)",
        "Chen 2018 Sec. 5.5.1 (bench identification)",
    ),
    ParamSpec(
        "output_namespace",
        "",
        "-",
        "namespace of the published <kind>/estimate and <kind>/phase_amplitude topics (e.g. "
        "an oracle filter's beside the device's); empty: the device's",
        "",
    ),
)

STATE_NAMES, STATE_UNITS = ("theta", "omega"), ("rad", "rad/s")
EVENT_NAMES, EVENT_UNITS = ("t_peak", "phase", "amplitude"), ("s", "rad", "rad")
KINDS = ("ekf", "ukf")


def _channel(msg, data: np.ndarray, name: str) -> np.ndarray:
    """Column ``name`` of a frame's data; FrameError when absent or non-finite."""
    names = list(msg.channel_names)
    if name not in names:
        raise FrameError(
            f"frame at {msg.first_sample_index}: no channel '{name}' (has {names})", "foreign"
        )
    col = data[:, names.index(name)]
    if not np.all(np.isfinite(col)):
        raise FrameError(f"frame at {msg.first_sample_index}: non-finite '{name}'", "non_finite")
    return col


class ScannerAmdmEstimatorNode(EstimatorNode):
    """EKF + UKF on the AMDM output of the shared-electrode scanner (module doc)."""

    GAP_NOTE = "filters reset (re-acquire)"

    NODE_NAME = "scanner_amdm_estimator"
    DEFAULT_NAMESPACE = "scanner_amdm"
    SPECS = sam.ESTIMATOR_SPECS + NODE_SPECS + input_specs()
    DIAGNOSTICS_TITLE = "EKF/UKF (shared electrodes)"
    #: A stream that starts (again) at or beyond this sample index is counted from its
    #: first sample for the drive alignment and the times of the extrema.
    BASE_INDEX = 2**50

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        p = self.p
        if p["params_yaml"]:
            # the node runs with (and reports) the identified model
            p.update(self.parameter_file("params_yaml", load_identification))
        est = self.values_of(sam.ESTIMATOR_SPECS)
        self.est_params = est
        self.fs = p["sample_rate_hz"]
        self._make_filters()
        self.pub_est = {
            k: self.create_publisher(StateEstimate, self._output(f"{k}/estimate"), FRAME_QOS)
            for k in KINDS
        }
        self.pub_evt = {
            k: self.create_publisher(StateEstimate, self._output(f"{k}/phase_amplitude"), FRAME_QOS)
            for k in KINDS
        }
        self.event_rate = 2.0 * math.sqrt(p["spring_constant"] / p["inertia"]) / (2 * math.pi)
        self.events_published = {k: 0 for k in KINDS}
        self.event_msgs = {k: 0 for k in KINDS}
        self._low_warned = False
        self.subscribe_pair(
            ("adc", AdcFrame, self._decode_adc),
            ("drive", SignalFrame, lambda msg: _channel(msg, signal_data(msg), "v_drive")),
        )

    def _output(self, name: str) -> str:
        """Output topic ``name``: in ``output_namespace``, else the device's."""
        ns = self.p["output_namespace"]
        return f"{ns.rstrip('/')}/{name}" if ns else self.device_topic(name)

    def _make_filters(self) -> None:
        est, fs = self.est_params, self.fs
        self.filters = {k: su.ScannerFilter(k, est) for k in KINDS}
        delay = est["chain_delay_s"]
        self.aligner = su.DriveAligner(delay * fs, self.filters["ekf"].model.vc2)
        self.trackers = {
            k: su.PhaseAmplitudeTracker(est["min_amplitude"], fs, delay) for k in KINDS
        }
        # sample index the drive alignment and the extrema count from: 0, or the first of
        # the stream after a restart beyond BASE_INDEX (float64 seconds and sample positions
        # cannot resolve samples that far)
        self._base: int | None = None

    def _decode_adc(self, msg: AdcFrame) -> np.ndarray:
        """y_cap [V] of an AMDM frame (its saturated samples counted)."""
        y = _channel(msg, adc_physical(msg), "y_cap")
        if msg.saturated_count:
            self.diag.count("saturated_samples", int(msg.saturated_count))
        return y

    def on_gap(self, gap: int) -> None:
        """Both filters start again (re-acquire)."""
        self._make_filters()

    def reset_estimator(self) -> None:
        """Both filters start again from their prior (re-acquire)."""
        self._make_filters()

    def process_pair(self, first: int, stamp_ns: int, y: np.ndarray, v: np.ndarray) -> None:
        """Run both filters on one paired frame and publish estimates and extrema."""
        if self._base is None:
            self._base = first if first >= self.BASE_INDEX else 0
        rel = first - self._base
        v2 = self.aligner.push(rel, v)
        delay_ns = int(round(self.est_params["chain_delay_s"] * 1e9))
        outs = {k: self.filters[k].step(y, v2) for k in KINDS}
        bad = [
            k
            for k in KINDS
            if self.filters[k].diverged() or not state_ok(outs[k]["x"], outs[k]["p"])
        ]
        if bad or not state_ok(v2):
            self.reset_estimator()
            raise Diverged("/".join(bad or KINDS).upper())
        for k in KINDS:
            out = outs[k]
            tr = self.trackers[k]
            tr.push_drive(rel, v)
            ev = tr.push_theta(rel, out["x"][:, 0], out["p"][:, 0], out["p"][:, 1])
            var = np.column_stack([out["p"][:, 0], out["p"][:, 1]])
            msg = output_frame(
                make_state_estimate,
                out["x"],
                var,
                first=first,
                fs=self.fs,
                stamp_ns=stamp_ns - delay_ns,
                estimator=f"scanner_{k}",
                state_names=STATE_NAMES,
                state_units=STATE_UNITS,
                frame_id=self.p["frame_id"],
            )
            self.pub_est[k].publish(msg)
            if ev.t.size:
                states = np.column_stack([ev.t, ev.phase, ev.amplitude])
                vars_ = np.column_stack([ev.var_t, ev.var_phase, ev.var_amplitude])
                em = output_frame(
                    make_state_estimate,
                    states,
                    vars_,
                    first=self.events_published[k],
                    fs=self.event_rate,
                    # event times count from the base sample: on the input's timeline
                    stamp_ns=stamp_ns - index_to_ns(rel, self.fs) + int(round(ev.t[0] * 1e9)),
                    estimator=f"scanner_{k}_phase",
                    state_names=EVENT_NAMES,
                    state_units=EVENT_UNITS,
                    frame_id=self.p["frame_id"],
                )
                self.pub_evt[k].publish(em)
                self.events_published[k] += int(ev.t.size)
                self.event_msgs[k] += 1
            f = self.filters[k]
            self.diag.counters[f"{k}_tracking"] = str(f.tracking)
            self.diag.counters[f"{k}_pd_failures"] = f.pd_failures
            self.diag.counters[f"{k}_acquisitions"] = f.acquisitions
            self.diag.counters[f"{k}_extrema"] = self.events_published[k]
        snr = su.ac_snr(y, self.est_params["output_noise_var"])
        self.diag.counters["ac_snr"] = f"{snr:.3g}"
        if any(f.tracking for f in self.filters.values()):
            self._low_warned = False
        else:
            self.diag.count("low_signal_frames")
            if self.filters["ekf"].samples >= self.filters["ekf"].window and not self._low_warned:
                self._low_warned = True  # logged once per loss of motion, counted always
                self.diag.warn(
                    "low signal: no motion observable on the AMDM output (AC SNR "
                    f"< acquire_snr {self.est_params['acquire_snr']}, see ac_snr); "
                    "drive far from parametric resonance? estimates held at 0"
                )
        for k, f in self.filters.items():
            if f.pd_failures and not self.diag.counters.get(f"{k}_pd_warned"):
                self.diag.counters[f"{k}_pd_warned"] = 1
                self.diag.warn(f"{k}: covariance lost positive definiteness (repaired)")


def main(argv: list[str] | None = None) -> int:
    """Entry point ``scanner_amdm_estimator_node``."""
    return run_node(ScannerAmdmEstimatorNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
