"""Tests of the IMU motion and temperature profiles (mems_sim.devices.imu_profiles), no ROS:
segment boundaries, temperature ramps and truth vectors against their closed forms, the
YAML round trip and errors that name the field."""

import math

import numpy as np
import pytest

from mems_sim.devices.imu_profiles import (
    BUILTIN_PROFILES,
    G0,
    ImuProfile,
    ProfileError,
    Segment,
    builtin_profile,
    dump_profile,
    load_profile,
    profile_truth,
)

DEG = math.pi / 180.0


def test_builtins_have_the_documented_layout():
    assert set(BUILTIN_PROFILES) >= {"six_position", "multi_position", "thermal_ramp"}
    six = builtin_profile("six_position")
    assert len(six.segments) == 6 and six.duration_s() == 360.0
    ups = [s.up_body for s in six.segments]
    assert ups == [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    assert all(s.rate_rad_s == 0.0 for s in six.segments)
    multi = builtin_profile("multi_position")
    assert len(multi.segments) == 12 and multi.duration_s() == 720.0
    assert multi.segments[:6] == six.segments
    rates = [(s.up_body, round(s.rate_rad_s / DEG, 9)) for s in multi.segments[6:]]
    assert rates == [
        ((1, 0, 0), 100.0),
        ((1, 0, 0), -100.0),
        ((0, 1, 0), 100.0),
        ((0, 1, 0), -100.0),
        ((0, 0, 1), 100.0),
        ((0, 0, 1), -100.0),
    ]
    ramp = builtin_profile("thermal_ramp")
    assert ramp.duration_s() == 2400.0 and len(ramp.segments) == 40
    assert ramp.segments[0].temperature_start_c == 20.0
    assert ramp.segments[-1].temperature_end_c == pytest.approx(60.0)
    for a, b in zip(ramp.segments, ramp.segments[1:]):
        assert a.temperature_end_c == pytest.approx(b.temperature_start_c)
        assert a.rate_rad_s == -b.rate_rad_s
    tm = builtin_profile("thermal_multi_position")
    assert len(tm.segments) == 48 and tm.duration_s() == 2880.0


def test_segment_starts_and_boundaries():
    """Segment i covers round(t_i fs) .. next start - 1; -1 after the end."""
    prof = ImuProfile(
        "t", (Segment(0.015, (0, 0, 1)), Segment(0.02, (1, 0, 0)), Segment(0.0125, (0, 1, 0)))
    )
    fs = 100.0
    starts = prof.segment_starts(fs)
    assert starts.dtype == np.int64
    assert starts.tolist() == [0, 2, 4]  # round(1.5) = 2, round(3.5) = 4 (half to even)
    assert prof.n_samples(fs) == 5  # round(4.75)
    tr = profile_truth(prof, 0, 8, fs)
    assert tr.segment.dtype == np.int32
    assert tr.segment.tolist() == [0, 0, 1, 1, 2, -1, -1, -1]
    # frames: any split gives the same truth
    a = profile_truth(prof, 0, 3, fs)
    b = profile_truth(prof, 3, 5, fs)
    for x, y, z in zip(a, b, tr):
        np.testing.assert_array_equal(np.concatenate([x, y]), z)


def test_truth_vectors_and_rate_table():
    prof = builtin_profile("multi_position")
    fs = 10.0
    for i, seg in enumerate(prof.segments):
        first = int(prof.segment_starts(fs)[i])
        tr = profile_truth(prof, first, 600, fs, temperature_c=31.0)
        up = np.array(seg.up_body)
        np.testing.assert_allclose(tr.accel, np.tile(G0 * up, (600, 1)), rtol=0, atol=0)
        np.testing.assert_allclose(tr.gyro, np.tile(seg.rate_rad_s * up, (600, 1)), atol=0)
        assert np.all(tr.segment == i)
        assert np.all(tr.temperature_c == 31.0)  # no temperature: the device's
    # z up gives the specific force [0, 0, +g] of truth_motion("static")
    assert profile_truth(prof, 4 * 600, 1, fs).accel.tolist() == [[0.0, 0.0, G0]]
    assert profile_truth(prof, 11 * 600, 1, fs).gyro[0, 2] == pytest.approx(-100 * DEG)


def test_thermal_ramp_temperature_is_linear_at_one_kelvin_per_minute():
    prof = builtin_profile("thermal_ramp")
    fs = 50.0
    n = prof.n_samples(fs)
    tr = profile_truth(prof, 0, n + 10, fs)
    t = np.arange(n + 10) / fs
    expected = np.minimum(20.0 + t / 60.0, 60.0)
    np.testing.assert_allclose(tr.temperature_c, expected, atol=1e-9)
    assert np.all(tr.segment[n:] == -1) and tr.segment[n - 1] == 39
    # held after the end: last segment's state
    np.testing.assert_array_equal(tr.gyro[n:], np.tile(tr.gyro[n - 1], (10, 1)))
    np.testing.assert_array_equal(tr.accel[n:], np.tile([0.0, 0.0, G0], (10, 1)))
    # rate table alternates +-100 deg/s about z every 60 s
    seg = tr.segment[:n]
    np.testing.assert_allclose(tr.gyro[:n, 2], np.where(seg % 2 == 0, 100, -100) * DEG)
    np.testing.assert_array_equal(tr.gyro[:, :2], 0.0)


def test_segment_ramp_defaults():
    """A segment ramps start -> end; end None holds the start; start None: device temperature."""
    prof = ImuProfile(
        "r",
        (
            Segment(1.0, (0, 0, 1), temperature_start_c=10.0, temperature_end_c=20.0),
            Segment(1.0, (0, 0, 1), temperature_start_c=30.0),
            Segment(1.0, (0, 0, 1)),
        ),
    )
    tr = profile_truth(prof, 0, 30, 10.0, temperature_c=-5.0)
    np.testing.assert_allclose(tr.temperature_c[:10], 10.0 + np.arange(10))
    assert np.all(tr.temperature_c[10:20] == 30.0)
    assert np.all(tr.temperature_c[20:] == -5.0)


def test_up_body_is_normalised():
    s = Segment(1.0, (1.0, 0.0, 1.0), rate_rad_s=2.0)
    assert s.up_body == pytest.approx((math.sqrt(0.5), 0.0, math.sqrt(0.5)))
    tr = profile_truth(ImuProfile("n", (s,)), 0, 1, 1.0)
    assert np.linalg.norm(tr.accel[0]) == pytest.approx(G0)
    assert np.linalg.norm(tr.gyro[0]) == pytest.approx(2.0)


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_yaml_round_trip(tmp_path, name):
    prof = builtin_profile(name)
    path = tmp_path / f"{name}.yaml"
    dump_profile(prof, path)
    assert load_profile(str(path)) == prof
    assert load_profile(name) == prof


def test_yaml_in_degrees_and_defaults(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text(
        "segments:\n"
        "  - {duration_s: 2, up_body: [0, 0, -1], rate_deg_s: 90, label: flip}\n"
        "  - {duration_s: 1.5, up_body: [1, 0, 0], temperature_start_c: 40}\n"
    )
    prof = load_profile(path)
    assert prof.name == "mine" and prof.settle_s == 1.0
    assert prof.segments[0].rate_rad_s == pytest.approx(math.pi / 2)
    assert prof.segments[0].up_body == (0.0, 0.0, -1.0) and prof.segments[0].label == "flip"
    assert prof.segments[1].temperature_start_c == 40.0
    assert prof.duration_s() == 3.5


@pytest.mark.parametrize(
    "text, field",
    [
        ("segments: []", "segments"),
        ("segments:\n  - {up_body: [0, 0, 1]}", "segments[0].duration_s is missing"),
        ("segments:\n  - {duration_s: -1, up_body: [0, 0, 1]}", "segments[0].duration_s"),
        ("segments:\n  - {duration_s: 1, up_body: [0, 0]}", "segments[0].up_body"),
        ("segments:\n  - {duration_s: 1, up_body: [0, 0, 0]}", "segments[0].up_body"),
        ("segments:\n  - {duration_s: 1, up_body: [0, a, 1]}", "segments[0].up_body[1]"),
        (
            "segments:\n  - {duration_s: 1, up_body: [0, 0, 1]}\n"
            "  - {duration_s: 1, up_body: [0, 0, 1], rate_deg_s: fast}",
            "segments[1].rate_deg_s",
        ),
        (
            "segments:\n  - {duration_s: 1, up_body: [0, 0, 1], rate_deg_s: 1, rate_rad_s: 1}",
            "segments[0]: give rate_deg_s or rate_rad_s",
        ),
        ("segments:\n  - {duration_s: 1, up_body: [0, 0, 1], speed: 3}", "segments[0]: unknown"),
        (
            "segments:\n  - {duration_s: 1, up_body: [0, 0, 1], temperature_end_c: hot}",
            "segments[0].temperature_end_c",
        ),
        ("settle_s: -1\nsegments:\n  - {duration_s: 1, up_body: [0, 0, 1]}", "settle_s"),
        ("segment:\n  - {duration_s: 1, up_body: [0, 0, 1]}", "unknown profile field"),
        ("segments: [", "cannot read YAML"),
    ],
)
def test_bad_yaml_names_the_field(tmp_path, text, field):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ProfileError) as info:
        load_profile(str(path))
    assert field in str(info.value) and "bad.yaml" in str(info.value)


def test_unknown_name_lists_builtins():
    with pytest.raises(ProfileError, match="six_position"):
        load_profile("no_such_profile")
