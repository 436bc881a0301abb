"""Parameter table of the pulse-actuated resonator and its sigma-delta loop
(:mod:`mems_sim.devices.resonator`), with the default pulse amplitude it derives from.

Every parameter of the resonator, the modulator, the controller and the observer with unit,
range and source (:class:`~mems_sim.params.ParamSpec`; Colinet, Galayko & Juillard);
docs/resonator.md.
"""

from __future__ import annotations

import math

from mems_sim.kernels.resonator_observer_model import DEFAULT_QUANTIZATION_VAR
from mems_sim.params import (
    AIR_QUALITY_FACTOR_TEMPCO,
    SILICON_RESONANCE_TEMPCO,
    ParamSpec,
    batch_spread,
)

__all__ = ["default_pulse_amplitude", "RESONATOR_SPECS"]

_FS = 1.0e6
_F0 = 0.05 * _FS
_Q = 100.0
_A_TARGET = 0.5


_WIDTH = 0.05  # default pulse width, fraction of T


def default_pulse_amplitude(
    amplitude: float = _A_TARGET,
    Q: float = _Q,
    f0_over_fs: float = 0.05,
    width: float = _WIDTH,
    timing: str = "sub_sample",
) -> float:
    """U = A (1 - exp(-pi/(2Q))) / (w cos(phi)), V (see module doc).

    Args:
        amplitude: target steady amplitude A, V. Q: quality factor. f0_over_fs: f0/fs.
        width: pulse width w, fraction of the sample period. timing: "sub_sample" (pulse
            centred on the crossing, phi = 0) or "on_sample" (fired at the first sample
            after the crossing: phi = pi f0/fs on average, plus half the width).
    """
    phi = 0.0 if timing == "sub_sample" else math.pi * f0_over_fs * (1.0 + width)
    return amplitude * -math.expm1(-math.pi / (2.0 * Q)) / (width * math.cos(phi))


_U = round(default_pulse_amplitude(), 6)

RESONATOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "sample_rate_hz",
        _FS,
        "Hz",
        "sample rate fs of the modulator and the digital loop",
        "chosen: 1 MHz (Colinet et al. work in units of fs, Sec. 6)",
        min=0.0,
        max=1.0e10,
        min_exclusive=True,
    ),
    ParamSpec(
        "f0_hz",
        _F0,
        "Hz",
        "resonator natural frequency f0 (must be < fs/2)",
        "Colinet Sec. 6: f0 = 0.05 fs (oversampling ratio 20)",
        min=0.0,
        max=5.0e9,
        min_exclusive=True,
        spread=batch_spread(0.02, "+-2 % resonance (flexure width tolerance)"),
        tempco=SILICON_RESONANCE_TEMPCO,
    ),
    ParamSpec(
        "quality_factor",
        _Q,
        "-",
        "quality factor Q of eq. (7) (> 0.5: underdamped)",
        "Colinet Sec. 6: Q = 100",
        min=0.5,
        max=1.0e7,
        min_exclusive=True,
        spread=batch_spread(0.20, "+-20 % quality factor (damping gap tolerance)"),
        tempco=AIR_QUALITY_FACTOR_TEMPCO,
    ),
    ParamSpec(
        "pulse_amplitude",
        _U,
        "V",
        "pulse height U, normalised input volts of eq. (7)",
        "chosen for a steady amplitude ~0.5 V with the default 50 ns sub-sample pulses: "
        "U = A(1-exp(-pi/2Q))/w, A = 0.5 V, w = 0.05 (default_pulse_amplitude)",
        min=0.0,
        max=100.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "pulse_width_s",
        _WIDTH / _FS,
        "s",
        "width of the force pulse (<= 1/fs)",
        "short-pulse actuation (Colinet Sec. 1); 50 ns = 0.05 T at 1 MHz keeps |x| "
        "over the pulse within 0.8 % of the amplitude; 1/fs = one-sample ZOH pulse",
        min=0.0,
        max=1.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "pulse_timing",
        "sub_sample",
        "-",
        "observer mode: pulses centred on the "
        "crossing predicted from the estimate (sub_sample, fast timing clock) or fired at "
        "the first sample after the estimate's crossing (on_sample); the comparator "
        "loop is always on_sample",
        "Colinet Sec. 6 ('pulses happen exactly at the "
        "equilibrium position instants'); see module doc",
        choices=("sub_sample", "on_sample"),
    ),
    ParamSpec(
        "output_noise_std",
        0.0,
        "V",
        "std of white noise b added at the resonator output (modulator input)",
        "Colinet Sec. 6: 'of the order of the signal' (scenarios set ~0.5 V); default 0",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "state_noise_std",
        0.0,
        "V",
        "std of thermomechanical force noise added to u each sample (process noise f of eq. (2))",
        "Colinet Sec. 7; default 0 (paper's Fig. 5)",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "mode",
        "observer",
        "-",
        "pulse controller: zero crossings of the Kalman estimate "
        "(observer, Fig. 4) or of the decoded bit stream (comparator, Fig. 1)",
        "Colinet Figs. 1 and 4",
        choices=("comparator", "observer"),
    ),
    ParamSpec(
        "comparator_input",
        "resonator",
        "-",
        "comparator mode: signal whose zero "
        "crossings fire the pulses: the noisy resonator output y+b (Fig. 1's one-bit "
        "comparator) or the decoded bit stream",
        "Colinet Fig. 1 (see module doc)",
        choices=("resonator", "bitstream"),
    ),
    ParamSpec(
        "comparator_window",
        5,
        "samples",
        "comparator mode: bits summed to decode the position (odd; 1 = raw bit stream)",
        "simplest boxcar decoder; 5 samples = 1/4 period at f0 = 0.05 fs",
        min=1,
        max=1001,
    ),
    ParamSpec(
        "f0_drift_ppm_per_s",
        0.0,
        "ppm/s",
        "linear drift of the true f0",
        "scenario knob; default none",
        min=-1.0e6,
        max=1.0e6,
    ),
    ParamSpec(
        "f0_step_fraction",
        0.0,
        "-",
        "relative step of the true f0 at f0_step_time_s",
        "scenario knob (acceptance: +0.02)",
        min=-0.5,
        max=0.5,
    ),
    ParamSpec(
        "f0_step_time_s",
        0.0,
        "s",
        "time of the f0 step (ignored if the fraction is 0)",
        "scenario knob",
        min=0.0,
        max=1.0e9,
    ),
    ParamSpec(
        "observer_f0_error",
        0.0,
        "-",
        "fractional error of f0 in the observer's model",
        "Colinet Sec. 7, Fig. 6: 5 % error",
        min=-0.5,
        max=0.5,
    ),
    ParamSpec(
        "observer_state_noise_std",
        0.0,
        "V",
        "force-noise std the observer assumes",
        "Colinet Sec. 7: F = 0 when the state noise is absent",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "observer_initial_std",
        0.0,
        "V",
        "std of the observer's initial resonator "
        "position/velocity uncertainty (0: it knows the rest start)",
        "start-up rule of this device (resonator at rest at k = 0)",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "quantization_var",
        DEFAULT_QUANTIZATION_VAR,
        "V^2",
        "quantisation-error variance assumed by the observer",
        "Delta^2/12 with Delta = 2 V (one-bit +-1 V)",
        min=0.0,
        max=10.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "quantizer_gain",
        1.0,
        "-",
        "quantiser gain kappa assumed by the in-loop observer "
        "(v = kappa q + w; 1: paper's eqs. (11)-(12))",
        "Bussgang alternative: "
        "sqrt(2/pi)/0.64 = 1.247 (mems_sim.kernels.resonator_observer.bussgang_quantizer)",
        min=0.0,
        max=10.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "sd_feedforward",
        0.5,
        "-",
        "modulator input feed-in c into the 2nd integrator "
        "(0.5: STF of eq. (11); 0: plain double loop, STF 0.5 z^-2/D)",
        "Colinet eqs. (10)-(12), see mems_sim.kernels.resonator_models",
        min=0.0,
        max=0.5,
    ),
    ParamSpec(
        "fast",
        True,
        "-",
        "steady-state (DARE) gain for the in-loop observer",
        "speed option; the exact time-varying gain otherwise",
    ),
    ParamSpec(
        "quantizer",
        "one_bit",
        "-",
        "modulator comparator: the one-bit quantiser of eqs. (10)-(12) (one_bit), or its "
        "linear-Gaussian stand-in (gaussian): v = q + w, w ~ N(0, quantization_var), in the "
        "same loop, so that the observer's model of eq. (13) is exact",
        "Colinet eqs. (10)-(13) (one_bit); gaussian: a test of the Kalman observer in the "
        "linear-Gaussian case its theory assumes (Anderson & Moore 1979)",
        choices=("one_bit", "gaussian"),
    ),
)
