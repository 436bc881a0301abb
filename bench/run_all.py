"""`make bench`: every benchmark of the project, each reporting ratios measured in one run."""

import runpy
import sys
from pathlib import Path

HERE = Path(__file__).parent

# (benchmark, options), in order; the stage graph as separate processes (~2.5 min: the
# one-process figures, zstd as recorded by default, the recorder with rosbag2's zstd_fast
# preset, the cheapest configuration, and zstd_fast with the stage paced at 1.5 x its
# sample rate: the headroom asked for; 9.8 s of data, 6.5 s of wall time at 1.5 x)
BENCHES = [
    ("bench_allan.py", []),
    ("bench_recorder.py", []),
    ("bench_recorder_split.py", []),
    ("bench_sd_resonator.py", []),
    ("bench_accelerometer.py", []),
    ("bench_scanner.py", []),
    ("bench_scanner_ukf.py", []),
    (
        "bench_stage_ekf.py",
        ["--graph-processes=zstd,zstd_fast,none:10000,zstd_fast@1.5", "--graph-periods=2400"],
    ),
    # the recorder's CPU and file size per storage preset and zstd level (~30 s)
    ("bench_recorder_presets.py", ["--repeat", "10", "--rounds", "2"]),
    # every scenario's fast-mode summary line (first frame to last), ~2 min
    ("bench_scenarios_fast.py", []),
    ("bench_imu_fast.py", []),
    # one device per graph (each family: device, its estimators, recorder), first frame to
    # last against 1x real time, ~15 s
    ("bench_single_device_fast.py", ["--repeat", "2"]),
    # each family's graph as separate processes (device paced at 1.5 x its sample rate,
    # estimators, calibration, zstd recorder of every topic): keeps up, frames lost, worst
    # frame delay, CPU per process (~6 min: the imu's calibration profile is 66 s of data)
    ("bench_device_processes.py", ["--pace", "1.5"]),
    # the stage with the scenario's 20,000-sample frames instead of the node's 5000 (~25 s)
    ("bench_device_processes.py", ["stage", "--frame-size", "stage=20000", "--pace", "1.5"]),
    # the families with two or more estimator nodes, those composed in one
    # component_container: their CPU against the separate processes of the run above (~2 min)
    ("bench_device_processes.py", ["imu", "resonator", "stage", "--compose", "--pace", "1.5"]),
    # 120 s of data: pacing at rates 1 and 10 and the lossless replay in ~3 min
    # (bench_replay.py alone defaults to the 600 s of the data-path figures)
    ("bench_replay.py", ["--duration", "120"]),
    ("bench_live_view.py", []),
    # 40 imu_noise runs of 600 s on 1 and 2 workers, 10 alone (~6 min)
    ("bench_campaign.py", ["--runs", "40", "--duration", "600"]),
    # 8 gyro_calibration runs (its own duration, ~25 s each) on 1 and 2 workers, 4 alone
    ("bench_campaign.py", ["--scenario", "gyro_calibration", "--runs", "8", "--duration", "0"]),
]

failed = []
for name, args in BENCHES:
    print(f"== {name} {' '.join(args)}".rstrip())
    sys.argv = [str(HERE / name)] + args
    # a benchmark that ends with sys.exit(main()) raises SystemExit here: the next ones
    # must still run (it ended make bench after bench_replay.py without a word)
    try:
        runpy.run_path(str(HERE / name), run_name="__main__")
    except SystemExit as exc:
        if exc.code not in (None, 0):
            print(f"== {name}: exit status {exc.code}")
            failed.append(name)
    print(flush=True)
if failed:
    sys.exit(f"make bench: {len(failed)} benchmark(s) failed: {', '.join(failed)}")
