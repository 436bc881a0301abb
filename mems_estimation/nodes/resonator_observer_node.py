"""ROS 2 node: Kalman observer (or adaptive observer) on a sigma-delta resonator's bit stream.

Subscribes ``<device>/adc`` (one-bit AdcFrame, codes -1/+1) and ``<device>/drive``
(the known pulses, SignalFrame: channel ``pulse`` [V] and, for sub-sample pulses,
``pulse_start`` [s] and ``pulse_width`` [s]; without them the pulses are one-sample ZOH
values) -- ``<device>/`` is ``device_namespace``, or nothing: relative names in the node's
namespace, default ``/resonator`` --, pairs the frames by ``first_sample_index``,
runs :class:`mems_sim.kernels.resonator_observer.KalmanObserver` (6 states: resonator,
STF, NTF; Colinet et al. eqs. 1-13) or, with ``adaptive: true``,
:class:`mems_estimation.filters.resonator_adaptive_observer.AdaptiveObserver` (state augmented
with f0), and publishes ``<device>/estimate`` or ``<device>/adaptive_estimate``
(mems_msgs/StateEstimate: position [V] and, adaptive, f0 [Hz], with variances).
A bit frame with codes other than -1/+1, a frame at another sample rate or of
another length than its drive frame is rejected and counted on /diagnostics (input path:
:class:`EstimatorNode`). Over a gap the observer continues without the missing samples; a
stream reset, or a divergence (non-finite state or covariance not positive definite, or,
adaptive, f0 outside (0, fs/2); counted ``divergences``, that frame's estimates not
published), starts it again from its prior.
Model: ``params_yaml`` names the identified model's YAML
(:mod:`mems_estimation.identification.resonator_identification`): its ``f0_hz`` and
``quality_factor`` replace the parameters' values (the node then runs with and reports
the identified model); empty: the parameters' values. ``f0_error`` then puts a relative
error on that f0 (a deliberately wrong model).

Health (Kalman observer; the adaptive observer keeps no innovations, so it has none): an
innovation consistency monitor (:class:`~mems_estimation.nodes.health.HealthReporter`,
:class:`~mems_estimation.filters.consistency_monitor.NisMonitor`) sums the normalised
innovation squared ``nu^2 / S`` of every sample whose estimate is published over windows of
``health_window`` samples against the thresholds of ``health_false_alarm``; each completed
window is published on the device's ``health`` (diagnostic_msgs/DiagnosticStatus: level OK,
WARN or ERROR, name the node's name, message the verdict, values the window's first sample
index, samples, statistic, thresholds and the designed false alarms per hour), and
/diagnostics carries the last verdict and statistic and the counts of WARN and ERROR
windows. The one-bit quantiser's error is neither white nor of the modelled variance 1/3
(Colinet et al. eq. 13 is an approximation), so the fault-free NIS is not chi-square: in
the Fig. 2 case (amplitude 0.25 V, output noise 0.25 V, state noise 5e-4 V) its mean per
sample is 1.13 and a window sum's variance 0.14-0.18 times chi-square's. The thresholds
are those of the scaled chi-square of ``health_nis_mean`` and ``health_nis_dispersion``,
measured on fault-free data of the configuration
(:func:`~mems_estimation.filters.consistency_monitor.nis_moments`); their defaults are the
Fig. 2 case's (another noise or amplitude has other moments: measure them). Moments 1 and
1 are the chi-square of Kalman theory, with which every window of that case is ERROR. The
monitor only reports: the estimate is the same with it. A re-initialised observer
(divergence, stream reset) starts a new window (the incomplete one is dropped); a window
continues over a gap.
"""

from __future__ import annotations

import numpy as np

from mems_estimation.filters.resonator_adaptive_observer import AdaptiveObserver
from mems_estimation.identification.resonator_identification import load_identification
from mems_estimation.nodes.frame_input import (
    DEVICE_NAMESPACE,
    Diverged,
    EstimatorNode,
    input_specs,
    output_frame,
)
from mems_estimation.nodes.health import HealthReporter, calibration_specs, health_specs
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.kernels.divergence import state_ok
from mems_sim.kernels.resonator_observer import KalmanObserver
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import FrameError, make_state_estimate, signal_data
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_QOS

OBSERVER_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec(
        "params_yaml",
        "",
        "-",
        "identified model YAML (resonator_identification): its f0_hz and quality_factor "
        "replace the parameters'; empty: the parameters' values",
        "the device identified on the bench from its own ring-downs, not its parameter table",
    ),
    ParamSpec(
        "adaptive",
        False,
        "-",
        "estimate f0 jointly with the state (adaptive observer)",
        "Colinet et al. Sec. 7-8 (named as future work)",
    ),
    ParamSpec(
        "sample_rate_hz",
        1.0e6,
        "Hz",
        "sample rate of the bit stream (frames at another rate are rejected)",
        "",
        min=0.0,
        max=1.0e9,
        min_exclusive=True,
    ),
    ParamSpec(
        "f0_hz",
        5.0e4,
        "Hz",
        "resonance frequency of the observer's model (initial value when adaptive)",
        "Colinet et al. Sec. 6: f0 = 0.05 fs",
        min=0.0,
        max=5.0e8,
        min_exclusive=True,
    ),
    ParamSpec(
        "quality_factor",
        100.0,
        "-",
        "quality factor of the observer's model",
        "Colinet et al. Sec. 6: Q = 100",
        min=0.0,
        max=1.0e9,
        min_exclusive=True,
    ),
    ParamSpec(
        "f0_error",
        0.0,
        "-",
        "relative error put on the model's f0 (of the parameters or of params_yaml): a "
        "deliberately wrong model",
        "Colinet et al. Sec. 6: the observer with a 5 % f0 error",
        min=-0.5,
        max=0.5,
    ),
    ParamSpec(
        "output_noise_std",
        0.0,
        "V",
        "std of the white noise at the resonator output the observer assumes",
        "",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "state_noise_std",
        0.0,
        "V",
        "std of the resonator state noise the observer assumes",
        "",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "f0_random_walk_ppm",
        0.2,
        "ppm/sqrt(sample)",
        "random walk of f0 in the adaptive observer's model",
        "",
        min=0.0,
        max=1.0e5,
    ),
    ParamSpec(
        "output_topic",
        "",
        "-",
        "StateEstimate topic; empty: the device's 'estimate' or 'adaptive_estimate'",
        "",
    ),
    ParamSpec("steady_state", False, "-", "use the steady-state Kalman gain (fast)", ""),
    *health_specs(
        10_000,
        "chosen: 10 ms at 1 MHz, 100 verdicts/s: 500 periods of f0 = 50 kHz, 16 ring-down "
        "times Q/(pi f0) (the observer's memory), so successive window sums are nearly "
        "independent (measured lag-1 correlation -0.01); an error of 1e-3 in the measured "
        "mean NIS moves the thresholds by 0.17 of a window's standard deviation",
    ),
    *calibration_specs(
        1.1297,
        0.175,
        "measured (nis_moments): Colinet et al. Fig. 2 case (amplitude 0.25 V, output noise "
        "0.25 V, state noise 5e-4 V), seeds 1 and 2, 2e6 samples each, windows of 10 000; "
        "other configurations differ: measure them",
    ),
)


def pulses_of(msg: SignalFrame) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(heights V, starts s or None, widths s or None) of a drive frame.

    Raises:
        FrameError: non-finite data, no ``pulse`` channel, or only one of the two timing
            channels.
    """
    data = signal_data(msg)
    names = list(msg.channel_names)
    if "pulse" not in names:
        raise FrameError(
            f"drive frame at {msg.first_sample_index}: no 'pulse' channel (channels {names})",
            "foreign",
        )
    timing = [c in names for c in ("pulse_start", "pulse_width")]
    if any(timing) and not all(timing):
        raise FrameError(
            f"drive frame at {msg.first_sample_index}: 'pulse_start' and "
            "'pulse_width' must come together"
        )
    u = np.ascontiguousarray(data[:, names.index("pulse")])
    if not all(timing):
        return u, None, None
    return (
        u,
        np.ascontiguousarray(data[:, names.index("pulse_start")]),
        np.ascontiguousarray(data[:, names.index("pulse_width")]),
    )


def bits_of(msg: AdcFrame) -> np.ndarray:
    """The -1/+1 codes of a one-bit AdcFrame.

    Raises:
        FrameError: not one channel, sizes inconsistent, or codes other than -1/+1
            (the convention of this project's one-bit streams).
    """
    if len(msg.channel_names) != 1 or len(msg.codes) != msg.num_samples:
        raise FrameError(
            f"bit frame at {msg.first_sample_index}: expected one channel of "
            f"{msg.num_samples} codes, got {len(msg.codes)} codes"
        )
    codes = np.asarray(msg.codes, dtype=np.int32)
    if not np.all(np.abs(codes) == 1):
        bad = codes[np.abs(codes) != 1][:3].tolist()
        raise FrameError(
            f"bit frame at {msg.first_sample_index}: codes {bad} are not -1/+1 "
            "(one-bit convention: -1 and +1)",
            "out_of_range",
        )
    return codes.astype(np.float64)


class ResonatorObserverNode(EstimatorNode):
    """Kalman / adaptive observer on the bit stream and pulses of a sigma-delta resonator."""

    GAP_NOTE = "the estimate continues without those samples"

    NODE_NAME = "resonator_observer"
    DEFAULT_NAMESPACE = "resonator"
    SPECS = OBSERVER_SPECS + input_specs()
    DIAGNOSTICS_TITLE = staticmethod(
        lambda p: "adaptive_observer" if p["adaptive"] else "kalman_observer"
    )

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        p = self.p
        if p["params_yaml"]:
            # the node runs with (and reports) the identified model
            p.update(self.parameter_file("params_yaml", load_identification))
        f0 = p["f0_hz"] * (1.0 + p["f0_error"])  # the model's f0 [Hz]
        self.fs = p["sample_rate_hz"]
        if f0 >= p["sample_rate_hz"] / 2:
            raise ParameterError(
                f"parameter 'f0_hz' = {p['f0_hz']!r} (with f0_error {p['f0_error']!r}) is out "
                f"of range: allowed (0, {p['sample_rate_hz'] / 2!r}) Hz (below fs/2)"
            )
        if p["adaptive"]:
            self.observer = AdaptiveObserver(
                f0,
                p["quality_factor"],
                p["sample_rate_hz"],
                p["output_noise_std"],
                p["state_noise_std"],
                f0_random_walk_ppm=p["f0_random_walk_ppm"],
            )
            self.names, self.units, self.estimator = (
                ("position", "f0"),
                ("V", "Hz"),
                "adaptive_observer",
            )
        else:
            self.observer = KalmanObserver(
                f0,
                p["quality_factor"],
                p["sample_rate_hz"],
                p["output_noise_std"],
                p["state_noise_std"],
                steady_state=p["steady_state"],
            )
            self.names, self.units, self.estimator = ("position",), ("V",), "kalman_observer"
        topic = p["output_topic"] or self.device_topic(
            "adaptive_estimate" if p["adaptive"] else "estimate"
        )
        self.pub = self.create_publisher(StateEstimate, topic, FRAME_QOS)
        self.health = None if p["adaptive"] else HealthReporter(self, self.fs, "Kalman observer")
        self.subscribe_pair(("adc", AdcFrame, bits_of), ("drive", SignalFrame, pulses_of))

    def reset_estimator(self) -> None:
        """The observer starts again from its prior; so does the health monitor's window."""
        self.observer.reset()
        if self.health is not None:
            self.health.reset()

    def process_pair(self, first: int, stamp_ns: int, bits: np.ndarray, drive) -> None:
        """Observer on one frame of bits with its pulses; publish the estimate."""
        pulses, starts, widths = drive
        try:
            out = self.observer.step(bits, pulses, starts, widths)
        except ValueError as exc:  # pulse timing outside [0, T) / (0, T]
            raise FrameError(str(exc)) from None
        if self.observer.diverged() or not state_ok(*out):
            self.reset_estimator()
            raise Diverged("adaptive observer" if self.p["adaptive"] else "Kalman observer")
        if self.p["adaptive"]:
            pos, pos_var, f0, f0_var = out
            states, var = np.column_stack([pos, f0]), np.column_stack([pos_var, f0_var])
        else:
            pos, pos_var = out
            states, var = pos.reshape(-1, 1), pos_var.reshape(-1, 1)
        msg = output_frame(
            make_state_estimate,
            states,
            var,
            first=first,
            fs=self.p["sample_rate_hz"],
            stamp_ns=stamp_ns,
            estimator=self.estimator,
            state_names=self.names,
            state_units=self.units,
            frame_id="resonator",
        )
        self.pub.publish(msg)
        if self.health is not None:
            innov = self.observer.last_innovations  # nu / sqrt(S)
            self.health.monitor_frame(first, innov * innov)


def main(argv: list[str] | None = None) -> int:
    """Entry point ``resonator_observer_node``."""
    return run_node(ResonatorObserverNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
