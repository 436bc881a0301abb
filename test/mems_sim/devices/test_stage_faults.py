"""Scheduled sensor faults on the stage's readout voltages, against the fault-free run of
the same seed: the ADC of the faulty voltages is the device's own rule, the codes of the
other channels and samples are untouched."""

import numpy as np

from mems_sim.devices.stage import CHANNELS, DriveSchedule, MicroStage
from mems_sim.devices.stage_readout import requantize
from mems_sim.hardware.fault_schedule import parse_schedule
from mems_sim.hardware.sensor_faults import SensorFaultInjector

SCHEDULE = DriveSchedule([(1700.0, 1.0, 4)])
N = 6000


def frames(entries=(), frame=1000, **params):
    st = MicroStage(params, SCHEDULE, seed=9)
    if entries:
        sched = parse_schedule({"faults": list(entries)}, CHANNELS, ("V",) * 4, st.fs)
        st.faults = SensorFaultInjector(sched, st.fs, 9, (st.noise_std,) * 4)
    out = [st.step(min(frame, N - k)) for k in range(0, N, frame)]
    return (
        np.concatenate([f.y for f in out]),
        np.concatenate([f.codes for f in out]),
        sum(f.saturated for f in out),
        st,
    )


def test_requantize_is_the_kernel_adc():
    """On a run that clips (a lowered full scale): the same codes and clipped count."""
    st = MicroStage({"adc_full_scale_v": 0.002}, DriveSchedule([(1700.0, 1.3, 40)]), seed=1)
    f = st.step(30000)
    again, n = requantize(f.y, 1.0 / st.lsb, float(st.code_max))
    np.testing.assert_array_equal(again, f.codes)
    assert n == f.saturated > 0


def test_bias_step_and_open_rail_on_one_channel():
    y0, c0, _, st = frames()
    b = 25.4 * st.lsb
    y1, c1, _, _ = frames(
        [
            {
                "kind": "bias_step",
                "channel": "2A",
                "start_sample": 1500,
                "duration_samples": 2000,
                "magnitude": b,
            },
        ],
        frame=777,
    )
    np.testing.assert_allclose(y1[1500:3500, 2] - y0[1500:3500, 2], b, rtol=1e-9)
    assert np.all(np.abs(c1[1500:3500, 2] - c0[1500:3500, 2] - b / st.lsb) <= 1)
    mask = np.ones(c0.shape, bool)
    mask[1500:3500, 2] = False
    np.testing.assert_array_equal(c1[mask], c0[mask])


def test_no_schedule_is_the_device_bit_for_bit():
    _, c0, _, _ = frames()
    _, c1, _, _ = frames([{"kind": "sign_flip", "channel": "1A", "start_sample": N}])
    np.testing.assert_array_equal(c1, c0)
