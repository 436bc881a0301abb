"""The estimation side: filters, identification and calibration, their nodes and tools."""

import mems_sim  # noqa: F401  (pins numpy's and OpenBLAS's kernels before numpy loads)
