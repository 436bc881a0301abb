"""`make bench`: every benchmark of the project, each reporting ratios measured in one run."""
import runpy
from pathlib import Path

HERE = Path(__file__).parent

for name in ("bench_allan.py", "bench_recorder.py", "bench_sd_resonator.py",
             "bench_accelerometer.py", "bench_scanner.py", "bench_scanner_ukf.py",
             "bench_stage_ekf.py"):
    print(f"== {name}")
    runpy.run_path(str(HERE / name), run_name="__main__")
    print()
