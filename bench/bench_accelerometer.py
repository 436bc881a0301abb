"""Benchmark: force-rebalance accelerometer (Zhang 2010) with the hybrid EKF in its loop.

Run:  .venv/bin/python bench/bench_accelerometer.py [n_samples]
Prints samples/s and the real-time factor (samples/s / fs) at fs = 1 MHz of the
device core in each controller mode (frames of 10,000 samples, the thesis's noise),
of the device node publishing its frames (ekf_rebalance, no subscriber), and of the
hybrid-EKF kernel alone (downstream filter on recorded frames). Numba compile /
cache load is done before timing.
"""

import os
import sys
import time

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

from mems_estimation.filters.accelerometer_ekf import HybridEkf
from mems_sim.devices import accelerometer

FS = 1e6
FRAME = 10_000


def _rate(fn, n):
    fn(FRAME)  # warm-up (numba cache / compile)
    t0 = time.perf_counter()
    fn(n)
    return n / (time.perf_counter() - t0)


def bench_device(mode: str, n: int) -> float:
    d = accelerometer.ForceRebalanceAccelerometer({"mode": mode}, seed=0)
    return _rate(lambda m: [d.step(FRAME) for _ in range(max(1, m // FRAME))], n)


def bench_node(n: int) -> float:
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from mems_sim.nodes.accelerometer_node import AccelerometerNode
    from mems_sim.ros.env import apply_defaults

    apply_defaults()
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ.get("ROS_DOMAIN_ID", "62")))
    try:
        node = AccelerometerNode(
            context=ctx,
            drive_externally=True,
            parameter_overrides=[
                Parameter("mode", value="ekf_rebalance"),
                Parameter("frame_size", value=FRAME),
            ],
        )
        r = _rate(lambda m: [node.step() for _ in range(max(1, m // FRAME))], n)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return r


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 2_000_000
    for mode in accelerometer.MODES:
        r = bench_device(mode, n)
        print(
            f"device core, {mode:13}: {r / 1e6:6.2f} Msamples/s = {r / FS:5.2f} x real time "
            "at fs = 1 MHz" + ("  (target >= 1x)" if mode == "ekf_rebalance" else "")
        )
    r = bench_node(n // 2)
    print(
        f"device node (publishing adc/drive/truth/loop_estimate), ekf_rebalance: "
        f"{r / 1e6:6.2f} Msamples/s = {r / FS:5.2f} x real time"
    )
    d = accelerometer.ForceRebalanceAccelerometer({"mode": "pi_rebalance"}, seed=1)
    f = d.step(n)
    y = f.code * d.lsb
    ekf = HybridEkf(d.ekf_config)
    r = _rate(lambda m: ekf.run(y[:m], f.v_f[:m]), n)
    print(
        f"hybrid EKF kernel alone (3 states, RK4 time update, Joseph update): "
        f"{r / 1e6:6.2f} Msamples/s = {r / FS:5.2f} x real time"
    )


if __name__ == "__main__":
    main()
