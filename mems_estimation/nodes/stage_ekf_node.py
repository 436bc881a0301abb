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

Health (streaming mode): an innovation consistency monitor
(:class:`~mems_estimation.nodes.health.HealthReporter`, windowed NIS test, Bar-Shalom, Li &
Kirubarajan 2001, Sec. 5.4.2) sums the normalised innovation squared nu^T S^-1 nu
(S = H P^- H^T + R, eqs. 50-51; n_y degrees of freedom per sample) of every sample with a
measurement update whose estimate is published (the bias-off samples carry none) over
windows of ``health_window`` such samples against the thresholds of ``health_false_alarm``:
those of the scaled chi-square with the filter's measured fault-free moments
(``health_nis_mean`` per degree of freedom, ``health_nis_dispersion``; Satterthwaite 1946),
since the fault-free NIS of the identified model on the drawn stage is not chi-square (mean
1.10 per degree of freedom, rising with the drive amplitude). Each completed window is
published on the device's ``health`` (diagnostic_msgs/DiagnosticStatus: level OK, WARN or
ERROR, name the node's name, message the verdict, values the window's first stream sample
index, samples, statistic, thresholds and the designed false alarms per hour at the rate of
the measured samples, fs / 2), and /diagnostics carries the last verdict and statistic and
the counts of WARN and ERROR windows. The monitor only reports: the estimate is the same
with it. A filter started again (divergence, stream reset, a gap too long to bridge)
starts a new window (the incomplete one is dropped); a window continues over a bridged
gap. The in-situ mode has no monitor.

In-situ mode (``insitu``; Chen 2018 eqs. 44-47 applied to the calibration sweep, the
in-situ correction of the stage model): the thesis processes a calibration sweep after its
acquisition, and so does the node. It keeps the sweep it receives (feedthrough-cancelled
channels [V], drive u [V], phase [cycle], trial, f_drive [Hz], each frame's first sample
index and stamp) and, once the sweep is complete, corrects the identified model's wn
[rad/s] and b_c [rad/(V s^2)] from the sweep's own channels (per trial the harmonics of the
cancelled channels, the tilt phasor through the sensor model of eqs. 44, 46-47, the
response pooled over the trials, the discrete response of eq. 34 matched to it), then runs
the EKF (eqs. 48-53) on the corrected model over the whole sweep without the output
correction (alpha = 1, beta = 0: the scale is the sensor's) and publishes the estimates as
frames with the first sample indices and stamps of the input frames. The sweep is complete
when the device's end-of-stream record (``end_of_stream``, latched) announces the end
sample index of its ``adc`` stream and the node has finished with the input up to it
(processed, rejected or dropped); a gap, a stream reset, ``insitu_max_samples`` samples
held or the node's shutdown end it too (the part held is processed as a sweep of its own).
The ratios corrected/identified of wn and b_c of the last sweep are on /diagnostics
(``insitu_wn_ratio``, ``insitu_b_c_ratio``); a sweep the correction cannot use is counted
(``insitu_failures``) and its estimates are not published.
"""

from __future__ import annotations

import numpy as np

from mems_estimation.filters.stage_ekf import (
    FAULT_FREE_NIS_DISPERSION,
    FAULT_FREE_NIS_MEAN,
    HEALTH_MOMENTS_SOURCE,
    HEALTH_WINDOW,
    FeedthroughCanceller,
    StageEkf,
    load_model,
)
from mems_estimation.identification.stage_insitu import insitu_correct
from mems_estimation.nodes.frame_input import (
    DEVICE_NAMESPACE,
    Diverged,
    EstimatorNode,
    adc_channels,
    drive_channels,
    input_specs,
    output_frame,
)
from mems_estimation.nodes.health import HealthReporter, calibration_specs, health_specs
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.kernels.divergence import state_ok
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import FrameError, make_state_estimate
from mems_sim.ros.node_main import run_node
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
    ParamSpec(
        "insitu",
        False,
        "-",
        "in-situ mode: keep the calibration sweep, correct wn and b_c of the model from its "
        "channels once it is complete, then run the EKF on the corrected model without the "
        "output correction (alpha = 1, beta = 0)",
        "Chen 2018 eqs. 44-47 (in-situ correction)",
    ),
    ParamSpec(
        "insitu_max_samples",
        4_000_000,
        "samples",
        "longest sweep kept in in-situ mode (about 72 bytes per sample with 4 channels); "
        "beyond it the part held is processed as a sweep of its own",
        "chosen: bounds the memory (a 7 x 400 period sweep at 625 kHz is 1.03e6 samples)",
        min=1,
        max=2**31 - 1,
    ),
    *health_specs(
        HEALTH_WINDOW,
        "chosen: samples with a measurement (bias on), 0.1 s at 625 kHz with the bias on "
        "every other drive period (10 verdicts/s, 85 bias-on periods at 1700 Hz)",
    ),
    *calibration_specs(FAULT_FREE_NIS_MEAN, FAULT_FREE_NIS_DISPERSION, HEALTH_MOMENTS_SOURCE),
)


def drive_columns(msg: SignalFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v_bias, f_drive) of a drive frame; FrameError when absent or non-finite."""
    return drive_channels(msg, ("u", "v_bias", "f_drive"))


#: Drive channels the in-situ mode keeps: the sweep's schedule besides the drive itself.
INSITU_DRIVE = ("u", "v_bias", "f_drive", "phase", "trial")


def drive_sweep_columns(msg: SignalFrame) -> tuple[np.ndarray, ...]:
    """(u [V], v_bias [V], f_drive [Hz], phase [cycle], trial [-]) of a drive frame (in-situ
    mode); FrameError when absent or non-finite."""
    cols = drive_channels(msg, INSITU_DRIVE)
    if not all(np.all(np.isfinite(c)) for c in cols):
        raise FrameError(
            f"drive frame at {msg.first_sample_index}: non-finite values", "non_finite"
        )
    return cols


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
        model = self.parameter_file("params_yaml", load_model)
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
        StageEkf(self.model).step(np.zeros((1, nch)), np.zeros(1), nis=True)
        FeedthroughCanceller(nch, self.model.fs).step(np.zeros((1, nch)), np.ones(1), np.ones(1))
        self.pub = self.create_publisher(StateEstimate, self.device_topic("estimate"), FRAME_QOS)
        #: in-situ mode: the sweep held (one tuple per frame), its samples, the end sample
        #: index the device announced, estimate frames published, sweeps processed
        self.insitu = bool(p["insitu"])
        self.sweep: list[tuple] = []
        self.sweep_samples = 0
        self.estimates_published = 0
        self.insitu_models: list = []
        #: the NIS monitor (streaming mode): n_y degrees of freedom per measured sample, at
        #: the rate of the measured samples (the bias on every other drive period: fs / 2)
        self.health = (
            None if self.insitu else HealthReporter(self, self.fs / 2, "stage EKF", dof=nch)
        )
        self.pub_health = None if self.health is None else self.health.pub
        self.subscribe_pair(
            ("adc", AdcFrame, self._decode_adc),
            ("drive", SignalFrame, drive_sweep_columns if self.insitu else drive_columns),
        )
        if self.insitu:
            self.follow_end_of_stream("adc")

    def _decode_adc(self, msg: AdcFrame) -> np.ndarray:
        """The selected channels of an ADC frame [V] (n, channels), C-contiguous; FrameError
        when absent or when the conversion overflows (the values are then all finite)."""
        return adc_channels(msg, self.channels, self.checked_codes(msg))

    def on_gap(self, gap: int) -> None:
        """The EKF continues with time updates only over the missing span (at most
        :attr:`BRIDGE_TIME_CONSTANTS` time constants; after a longer one it starts again at
        the forced steady state under the next frame's drive); the feedthrough
        cancellation starts again."""
        if self.insitu:
            self.process_sweep()
            self.canceller.reset()
            return
        m = self.model
        bridge = self.BRIDGE_TIME_CONSTANTS * m.fs / (m.zeta * m.wn)
        if gap <= bridge:
            self.ekf.time_update(gap)
        else:
            self._start_forced = True
            self.health.reset()
        self.canceller.reset()

    def on_stream_reset(self, ahead: bool) -> None:
        """A jump ahead (the stage ran on unseen, longer than any bridged gap) starts the
        EKF again at the forced steady state under the next frame's drive
        (:meth:`StageEkf.start_forced`); a stream that started again (a stage that starts at
        rest), from its prior. In-situ mode: the sweep held is processed first."""
        if self.insitu:
            self.process_sweep()
        if ahead:
            self.on_gap(2**63)
        else:
            self.reset_estimator()

    def reset_estimator(self) -> None:
        """The EKF starts again from its prior, the feedthrough cancellation from no
        history, the health monitor with a new window."""
        self.ekf.reset()
        self.canceller.reset()
        self._start_forced = False
        if self.health is not None:
            self.health.reset()

    def process_pair(self, first: int, stamp_ns: int, y: np.ndarray, drive) -> None:
        """Cancel the feedthrough, run the EKF on one frame and publish theta, omega
        (in-situ mode: keep the cancelled frame and its drive for the sweep)."""
        if self.insitu:
            u, vb, fd, phase, trial = drive
            yc = self.canceller.step(y, vb, fd)
            if self.sweep_samples + u.size > self.p["insitu_max_samples"]:
                self.diag.warn(
                    f"in-situ sweep longer than insitu_max_samples = "
                    f"{self.p['insitu_max_samples']}: processed at index {first}"
                )
                self.process_sweep()
            self.sweep.append((first, stamp_ns, yc, u, phase, trial.astype(np.int64), fd))
            self.sweep_samples += u.size
            return
        u, vb, fd = drive
        if self._start_forced:
            self.ekf.start_forced(u, fd)
            self._start_forced = False
        yc = self.canceller.step(y, vb, fd)
        x, v, nis = self.ekf.step(yc, u, corrected=self.p["output_correction"], nis=True)
        if self.ekf.diverged() or not state_ok(x, v):
            self.reset_estimator()
            raise Diverged("stage EKF")
        self._publish_estimate(first, stamp_ns, x, v)
        self.health.monitor_frame(first, nis, np.isfinite(yc).all(axis=1))

    # ------------------------------------------------------------------ in-situ mode

    def input_ended(self) -> None:
        """In-situ mode: the device announced the end of its ``adc`` stream and the node
        has finished with the input up to it: the sweep is complete."""
        if self.insitu:
            self.process_sweep()

    def process_sweep(self) -> None:
        """In-situ mode: correct the model from the sweep held (wn, b_c: eqs. 44-47 and
        34), run the EKF (eqs. 48-53) on the corrected model over the whole sweep with
        alpha = 1, beta = 0 and publish the estimates frame by frame (module doc)."""
        sweep, self.sweep, self.sweep_samples = self.sweep, [], 0
        if not sweep:
            return
        yc, u, phase, trial, fd = (np.concatenate([f[k] for f in sweep]) for k in (2, 3, 4, 5, 6))
        try:
            m, _ = insitu_correct(self.model, yc, u, phase, trial, fd)
        except ValueError as exc:
            self.diag.count("insitu_failures")
            self.diag.warn(f"in-situ sweep at index {sweep[0][0]} not used: {exc}")
            return
        ekf = StageEkf(m)
        x, v = ekf.step(yc, u, corrected=False)
        if ekf.diverged() or not state_ok(x, v):
            self.note_divergence("stage EKF (in-situ sweep)", sweep[0][0])
            return
        self.insitu_models.append(m)
        self.diag.count("insitu_sweeps")
        self.diag.counters["insitu_wn_ratio"] = float(m.extra["insitu_wn_ratio"])
        self.diag.counters["insitu_b_c_ratio"] = float(m.extra["insitu_b_c_ratio"])
        self.diag.publish()  # the corrected model on /diagnostics now, not a period later
        k = 0
        for first, stamp_ns, _, uf, *_ in sweep:
            n = uf.size
            self._publish_estimate(first, stamp_ns, x[k : k + n], v[k : k + n])
            k += n

    def _publish_estimate(self, first: int, stamp_ns: int, x, v) -> None:
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
        self.estimates_published += 1

    def close(self) -> None:
        """At shutdown (in-situ mode): the sweep held is processed."""
        if self.insitu:
            self.process_sweep()


def main(argv: list[str] | None = None) -> int:
    """Entry point ``stage_ekf_node``."""
    return run_node(StageEkfNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
