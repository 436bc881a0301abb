"""ROS 2 node of the chapter-5 micro-scanner with shared electrodes and the AMDM read-out
(thin wrapper of :mod:`mems_sim.devices.scanner_amdm`; Chen 2018 ch. 5).

Topics (relative to the namespace, default ``/scanner_amdm``):
    ``adc``    mems_msgs/AdcFrame     y_cap codes of the AMDM output (16 bit, +-10 V), decimated
    ``drive``  mems_msgs/SignalFrame  v_drive [V] (the unipolar drive V_dr at the output instants),
                                      f_drive [Hz]
    ``truth``  mems_msgs/SignalFrame  theta [rad], omega [rad/s] at the output instants
    ``faults`` mems_msgs/FaultEvent   each fault of ``fault_schedule`` when it begins (timing
                                      kinds only: ``dropped_samples``)
    ``/diagnostics``
Input: ``temperature`` sensor_msgs/Temperature: the device's temperature (``temperature_c``).
Parameters: ``mems_sim.devices.scanner_amdm.AMDM_SPECS``, ``device_seed`` and ``temperature_c``
(the device drawn from the table's spreads at a temperature, reference 25 C) and
``EMULATOR_SPECS``; the envelope delay of
the chain (``chain_delay_s`` of the estimator) is logged at start and published on /diagnostics.
"""

from __future__ import annotations

import numpy as np

from mems_sim.devices import scanner_amdm
from mems_sim.hardware.fault_schedule import TIMING_ONLY
from mems_sim.nodes.fault_topic import FAULT_SCHEDULE_SPEC, FaultTopic
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import make_adc_frame
from mems_sim.ros.node_base import EmulatorNode, emulator_specs, variation_specs
from mems_sim.ros.node_main import run_node

NODE_SPECS: tuple[ParamSpec, ...] = emulator_specs(frame_size=10000, frame_id="scanner")

ADC_CHANNEL = "y_cap"
DRIVE_CHANNELS = ("v_drive", "f_drive")
DRIVE_UNITS = ("V", "Hz")
TRUTH_CHANNELS = ("theta", "omega")
TRUTH_UNITS = ("rad", "rad/s")


class ScannerAmdmNode(EmulatorNode):
    """Emulated shared-electrode scanner + AMDM chain publishing ADC, drive and truth frames.

    Keyword arguments: those of :class:`~mems_sim.ros.node_base.EmulatorNode`.
    """

    NODE_NAME = "scanner_amdm"
    DEFAULT_NAMESPACE = "scanner_amdm"
    SPECS = scanner_amdm.AMDM_SPECS + variation_specs() + NODE_SPECS + (FAULT_SCHEDULE_SPEC,)
    DEVICE_SPECS = scanner_amdm.AMDM_SPECS
    DIAGNOSTICS_TITLE = "shared-electrode scanner (AMDM)"

    def make_device(self) -> float:
        self.device = scanner_amdm.AmdmScannerDevice(self.device_values(), seed=self.p["seed"])
        self.pub_adc, self.pub_drive, self.pub_truth = self.create_frame_publishers(
            "adc", "drive", "truth"
        )
        self.fault_topic = FaultTopic(
            self, (ADC_CHANNEL,), ("V",), self.device.fs, kinds=TIMING_ONLY
        )
        self.diag.counters["chain_delay_s"] = f"{self.device.delay:.6e}"
        self.get_logger().info(
            f"AMDM chain envelope delay {self.device.delay * 1e6:.4f} us "
            f"(estimator parameter chain_delay_s)"
        )
        return self.device.fs

    def publish_frame(self, first: int, n: int) -> None:
        self.fault_topic.publish_starting(first, n)
        f = self.device.step(n)
        fs_ = self.p["adc_full_scale"]
        common = self.frame_kwargs
        self.pub_adc.publish(
            make_adc_frame(
                f.codes.reshape(n, 1),
                first,
                self.fs,
                bits=self.p["adc_bits"],
                channel_names=(ADC_CHANNEL,),
                channel_units=("V",),
                lsb=(self.device.lsb,),
                full_scale=(fs_,),
                saturated_count=f.saturated,
                **common,
            )
        )
        self.publish_signals(
            self.pub_drive,
            first,
            np.column_stack([f.drive, f.drive_freq]),
            DRIVE_CHANNELS,
            DRIVE_UNITS,
        )
        self.publish_signals(
            self.pub_truth, first, np.column_stack([f.theta, f.omega]), TRUTH_CHANNELS, TRUTH_UNITS
        )
        if f.saturated:
            self.diag.count("saturated_samples", f.saturated)
            self.diag.warn(f"ADC saturated on {f.saturated} samples of frame {first}")


def main(argv: list[str] | None = None) -> int:
    """Entry point ``scanner_amdm_node``."""
    return run_node(ScannerAmdmNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
