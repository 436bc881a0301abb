"""`make bench`: every benchmark of the project, each reporting ratios measured in one run."""

import runpy
import sys
from pathlib import Path

HERE = Path(__file__).parent

# options per benchmark: the stage graph as separate processes (~90 s: the one-process
# figures, zstd as recorded by default and the cheapest configuration)
ARGS = {"bench_stage_ekf.py": ["--graph-processes=zstd,none,none:10000"]}

for name in (
    "bench_allan.py",
    "bench_recorder.py",
    "bench_sd_resonator.py",
    "bench_accelerometer.py",
    "bench_scanner.py",
    "bench_scanner_ukf.py",
    "bench_stage_ekf.py",
):
    print(f"== {name}")
    sys.argv = [str(HERE / name)] + ARGS.get(name, [])
    runpy.run_path(str(HERE / name), run_name="__main__")
    print()
