"""ROS 2 node of the electrostatic comb-drive micro-scanner (thin wrapper of
:mod:`mems_sim.devices.scanner`; Chen 2018 ch. 4, and ch. 5 through :mod:`mems_sim.devices.scanner_amdm`).

Front end (parameter ``front_end``):

* ``dc_transimpedance`` (chapter 4): y_cap = -R_s V_bias dC_s/dt + noise, eq. (64), at fs.
* ``shared_amdm`` (chapter 5): drive + carrier on the same electrodes through the AMDM chain;
  implemented by :class:`mems_sim.devices.scanner_amdm.AmdmScannerDevice` (other module, Table 5.2
  defaults, ``seed`` shared) -- this node only publishes its frames.  The dedicated
  chapter-5 node with all AMDM parameters is ``mems_sim.nodes.scanner_amdm_node``.

Topics (relative to the namespace, default ``/scanner``):
    ``adc``    mems_msgs/AdcFrame     y_cap codes (16 bit, +-10 V: the NI PCIe-6251 of Sec. 4.4.1)
    ``drive``  mems_msgs/SignalFrame  v_drive [V] (held over the sample), f_drive [Hz]
    ``truth``  mems_msgs/SignalFrame  theta [rad], omega [rad/s]
    ``psd``    mems_msgs/SignalFrame  theta_psd [rad]: PSD-like reference delayed by
                                      ``psd_delay_s`` (dc_transimpedance only)
    ``/diagnostics``                   frames, saturated samples, psd delay
Input: ``temperature`` sensor_msgs/Temperature: the device's temperature (``temperature_c``).
Parameters: ``SCANNER_SPECS`` + ``device_seed`` and ``temperature_c`` (the device drawn from the
table's spreads at a temperature, reference 25 C; ``dc_transimpedance`` only: the
``shared_amdm`` front end here is the nominal Table 5.2 device, ``scanner_amdm_node`` draws
it) + ``front_end`` + ``drive_frequency_hz`` + ``fault_schedule`` (``dc_transimpedance``:
sensor faults on the readout voltage before the ADC, channel ``y_cap``, labelled on
``faults``; docs/faults.md) + ``EMULATOR_SPECS``
(default ``frame_size`` 10000 samples = 20 ms: with the estimator and the recorder in one
process the graph keeps up with 500 kHz only with frames of ~10^4 samples, as measured by make bench).
"""

from __future__ import annotations

import numpy as np

from mems_sim.devices import scanner as micro_scanner
from mems_sim.hardware.fault_schedule import FAULT_KINDS, TIMING_ONLY
from mems_sim.nodes.fault_topic import FAULT_SCHEDULE_SPEC, FaultTopic
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import make_adc_frame
from mems_sim.ros.node_base import EmulatorNode, emulator_specs, variation_specs
from mems_sim.ros.node_main import run_node

NODE_SPECS: tuple[ParamSpec, ...] = emulator_specs(frame_size=10000, frame_id="scanner") + (
    ParamSpec(
        "front_end",
        "dc_transimpedance",
        "-",
        "sensing front end",
        "Chen 2018: dc_transimpedance (ch. 4, eq. 64) or shared_amdm (ch. 5, AMDM chain)",
        choices=micro_scanner.FRONT_ENDS,
    ),
    ParamSpec(
        "drive_frequency_hz",
        0.0,
        "Hz",
        "constant drive frequency instead of the sweep/hold/cut-off programme (0: programme)",
        "test knob (far from resonance)",
        min=0.0,
        max=1.0e6,
    ),
    ParamSpec("adc_bits", 16, "bit", "ADC resolution", "NI PCIe-6251 (Sec. 4.4.1)", min=2, max=31),
    ParamSpec(
        "adc_full_scale",
        10.0,
        "V",
        "ADC full scale +-",
        "NI PCIe-6251 +-10 V",
        min=0.0,
        max=1.0e3,
        min_exclusive=True,
    ),
)

ADC_CHANNEL = "y_cap"
DRIVE_CHANNELS = ("v_drive", "f_drive")
DRIVE_UNITS = ("V", "Hz")
TRUTH_CHANNELS = ("theta", "omega")
TRUTH_UNITS = ("rad", "rad/s")


def quantize(y: np.ndarray, bits: int, full_scale: float) -> tuple[np.ndarray, float, int]:
    """(codes int32, lsb V, clipped count): round(y / lsb) clipped to the signed range."""
    lsb = 2.0 * full_scale / 2**bits
    hi = 2 ** (bits - 1) - 1
    lo = -(2 ** (bits - 1))
    c = np.rint(y / lsb)
    sat = int(np.count_nonzero((c > hi) | (c < lo)))
    return np.clip(c, lo, hi).astype(np.int32), lsb, sat


class ScannerNode(EmulatorNode):
    """Emulated micro-scanner publishing ADC, drive, truth (and PSD reference) frames.

    Keyword arguments: those of :class:`~mems_sim.ros.node_base.EmulatorNode`.
    """

    NODE_NAME = "scanner"
    DEFAULT_NAMESPACE = "scanner"
    SPECS = micro_scanner.SCANNER_SPECS + variation_specs() + NODE_SPECS + (FAULT_SCHEDULE_SPEC,)
    DEVICE_SPECS = micro_scanner.SCANNER_SPECS
    DIAGNOSTICS_TITLE = staticmethod(lambda p: f"micro-scanner ({p['front_end']})")

    def make_device(self) -> float:
        p = self.p
        self.front_end = p["front_end"]
        fdrive = p["drive_frequency_hz"] or None
        if self.front_end == "dc_transimpedance":
            dev = self.device_values()
            self.device = micro_scanner.MicroScannerDevice(
                dev, seed=p["seed"], drive_frequency_hz=fdrive
            )
        else:
            # ---- shared_amdm: chapter-5 front end, implemented in mems_sim.devices.scanner_amdm ----
            from mems_sim.devices import scanner_amdm

            self.device = scanner_amdm.AmdmScannerDevice(seed=p["seed"])
        # the shared_amdm front end has the timing kinds only (no sensor-fault injection yet)
        kinds = FAULT_KINDS if self.front_end == "dc_transimpedance" else TIMING_ONLY
        self.fault_topic = FaultTopic(
            self, (ADC_CHANNEL,), ("V",), self.device.fs, (self._noise_std(),), kinds
        )
        self.pub_adc, self.pub_drive, self.pub_truth = self.create_frame_publishers(
            "adc", "drive", "truth"
        )
        self.pub_psd = None
        if self.front_end == "dc_transimpedance":
            (self.pub_psd,) = self.create_frame_publishers("psd")
            self.diag.counters["psd_delay_s"] = self.device.psd_delay
        return self.device.fs

    def _frame(self, first: int, n: int):
        """(codes, lsb, saturated, drive, f_drive, theta, omega, psd or None) of n samples."""
        if self.front_end == "dc_transimpedance":
            f = self.device.step(n)
            y = f.y
            if self.fault_topic.injector:
                y = self.fault_topic.injector.apply(y.reshape(n, 1), first)[:, 0]
            codes, lsb, sat = quantize(y, self.p["adc_bits"], self.p["adc_full_scale"])
            if self.device.const_freq is not None:
                fd = np.full(n, self.device.const_freq)
            else:
                fd = np.zeros(n)
                hi = min(first + n, self.device.total_samples)
                if hi > first:
                    fd[: hi - first] = self.device.plan.frequency[first:hi]
            return codes, lsb, sat, f.drive, fd, f.theta, f.omega, f.psd
        f = self.device.step(n)
        return (
            f.codes,
            self.device.lsb,
            f.saturated,
            f.drive,
            f.drive_freq,
            f.theta,
            f.omega,
            None,
        )

    def _noise_std(self) -> float:
        """White readout noise per sample of the ADC input [V] (a noise_burst's sigma)."""
        return float(getattr(self.device, "p", {}).get("noise_std", 0.0))

    def publish_frame(self, first: int, n: int) -> None:
        self.fault_topic.publish_starting(first, n)
        codes, lsb, sat, v, fd, th, om, psd = self._frame(first, n)
        common = self.frame_kwargs
        fsc = (
            self.p["adc_full_scale"]
            if self.front_end == "dc_transimpedance"
            else self.device.p["adc_full_scale"]
        )
        bits = (
            self.p["adc_bits"]
            if self.front_end == "dc_transimpedance"
            else self.device.p["adc_bits"]
        )
        self.pub_adc.publish(
            make_adc_frame(
                np.asarray(codes).reshape(n, 1),
                first,
                self.fs,
                bits=bits,
                channel_names=(ADC_CHANNEL,),
                channel_units=("V",),
                lsb=(lsb,),
                full_scale=(fsc,),
                saturated_count=sat,
                **common,
            )
        )
        self.publish_signals(
            self.pub_drive, first, np.column_stack([v, fd]), DRIVE_CHANNELS, DRIVE_UNITS
        )
        self.publish_signals(
            self.pub_truth, first, np.column_stack([th, om]), TRUTH_CHANNELS, TRUTH_UNITS
        )
        if psd is not None:
            self.publish_signals(self.pub_psd, first, psd.reshape(n, 1), ("theta_psd",), ("rad",))
        if sat:
            self.diag.count("saturated_samples", sat)
            self.diag.warn(f"ADC saturated on {sat} samples in frame {first}")


def main(argv: list[str] | None = None) -> int:
    """Entry point ``scanner_node``."""
    return run_node(ScannerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
