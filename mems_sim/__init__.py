"""The hardware side: device models, their kernels, emulator nodes, ROS plumbing, bag tools.

Importing the package pins numpy's and OpenBLAS's kernel choice before numpy loads
(:mod:`mems_sim.cpu_pins`), so that every executable gives the same floats on every x86-64
CPU with AVX2 and FMA.
"""

from mems_sim import cpu_pins as _cpu_pins

_cpu_pins.apply()
