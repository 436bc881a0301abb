"""``identify_noise`` in process for the tests: exit status and what it printed."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from mems_estimation.tools.identify_noise import main

#: The shipped IMU recording (``make bags``).
IMU_BAG = Path(__file__).resolve().parents[1] / "bags" / "imu.mcap"


def run_identify_noise(args: list) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of ``identify_noise ARGS`` (each argument str()'d)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()
