"""Whether a recording follows the calibration profile it is calibrated with.

A multi-position or rate-table calibration fits y = b + C u per axis over the segments. Fed
data that do not follow the profile (a static recording, another profile, a recording that
starts late), the fit still succeeds and returns a confident wrong answer: on a static
record every accelerometer matrix entry comes out ~0 and the z bias ~g. Before the fit,
each segment's measured mean is therefore compared with the profile's mean of the same
segment, per sensor (the residual of the nominal model y = u):

    |y_s - u_s| <= REL_TOL |u_s| + FLOOR[sensor]

REL_TOL (20 %) and the floors (0.15 rad/s, 1.5 m/s^2) cover any MEMS part's scale-factor
error, misalignment and bias (consumer parts: a few %, +-5 deg/s = 0.09 rad/s, +-60 mg =
0.6 m/s^2) with margin, while a position seen on the wrong axis differs by |g| sqrt(2)
(13.9 m/s^2) and a missing rate-table rate by the rate itself.
"""

from __future__ import annotations

import numpy as np

#: relative part of the allowed difference between a segment's measured and profile mean [1]
REL_TOL = 0.2
#: absolute part of the allowed difference per sensor: gyro [rad/s], accel [m/s^2]
FLOOR = {"gyro": 0.15, "accel": 1.5}
_UNIT = {"gyro": "rad/s", "accel": "m/s^2"}


def _vec(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:.3g}" for x in v) + "]"


def profile_mismatch(st) -> str | None:
    """None when every segment's measured means follow the profile (module docstring), else
    one line naming how many segments do not and the first of them.

    Args:
        st: :class:`mems_estimation.identification.imu_calibration.SegmentStats` (measured
            means y [rad/s, m/s^2], profile means w [rad/s] and f [m/s^2], times t0, t1 [s]).
    """
    bad = []
    for k in range(st.segment.size):
        for sensor, measured, truth in (
            ("gyro", st.y[k, :3], st.w[k]),
            ("accel", st.y[k, 3:], st.f[k]),
        ):
            allowed = REL_TOL * np.linalg.norm(truth) + FLOOR[sensor]
            if np.linalg.norm(measured - truth) > allowed:
                bad.append((k, sensor, measured, truth))
                break
    if not bad:
        return None
    k, sensor, measured, truth = bad[0]
    return (
        f"the data do not follow the profile: {len(bad)} of {st.segment.size} segments differ "
        f"from it by more than {REL_TOL:.0%} of its value + {FLOOR[sensor]:g} {_UNIT[sensor]} "
        f"(segment "
        f"{int(st.segment[k])}, {st.t0[k]:.4g}-{st.t1[k]:.4g} s: {sensor} mean "
        f"{_vec(measured)} {_UNIT[sensor]}, profile {_vec(truth)}); is this a recording of "
        "this profile, from its start?"
    )
