"""The resonator bench for tests: ring-downs of a device
(:func:`mems_estimation.studies.resonator_bench.bench_ringdowns`)."""

from mems_estimation.studies.resonator_bench import bench_ringdowns

__all__ = ["bench_ringdowns"]
