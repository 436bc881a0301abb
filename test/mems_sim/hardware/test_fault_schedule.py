"""The fault schedule file: entries in samples of the device clock, and one-line errors
naming the entry and the field for every mistake."""

import pytest

from mems_sim.hardware.fault_schedule import (
    FAULT_KINDS,
    FaultScheduleError,
    delivered_runs,
    load_schedule,
    parse_schedule,
)

CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
UNITS = ("rad/s",) * 3 + ("m/s^2",) * 3
FS = 200.0


def parse(*entries):
    return parse_schedule({"faults": list(entries)}, CHANNELS, UNITS, FS)


def test_entries_in_samples_with_units_and_order():
    a, b, c = parse(
        {
            "kind": "bias_step",
            "channel": "gyro_z",
            "start_s": 2.0,
            "duration_s": 0.5,
            "magnitude": 0.01,
        },
        {
            "kind": "spikes",
            "channel": "accel_x",
            "start_sample": 7,
            "duration_samples": 30,
            "magnitude": 0.5,
            "rate_hz": 5.0,
        },
        {"kind": "stuck_at", "channel": "accel_z", "start_s": 0.0126},
    )
    assert (a.first, a.count, a.end, a.unit, a.channel_index) == (400, 100, 500, "rad/s", 2)
    assert (b.first, b.count, b.unit, b.rate_hz, b.number) == (7, 30, "m/s^2", 5.0, 1)
    assert c.permanent and c.end is None and c.first == 3 and c.magnitude == 0.0
    assert parse()[0:0] == () and parse_schedule({"faults": None}, CHANNELS, UNITS, FS) == ()
    ramp = parse({"kind": "bias_ramp", "channel": "gyro_x", "start_sample": 0, "magnitude": 1.0})
    assert ramp[0].unit == "rad/s/s"


def test_overlap_of_a_block():
    (e,) = parse(
        {"kind": "sign_flip", "channel": "gyro_x", "start_sample": 10, "duration_samples": 5}
    )
    assert e.overlap(0, 10) == (0, 0)
    assert e.overlap(0, 12) == (10, 12)
    assert e.overlap(12, 100) == (0, 3)
    assert e.overlap(15, 10) == (0, 0)
    (p,) = parse({"kind": "sign_flip", "channel": "gyro_x", "start_sample": 10})
    assert p.overlap(1000, 8) == (0, 8)


@pytest.mark.parametrize(
    "entry, words",
    [
        ({"kind": "melt", "channel": "gyro_x", "start_s": 0}, "'kind' = 'melt' is not a fault"),
        (
            {"kind": "bias_step", "channel": "mag_x", "start_s": 0, "magnitude": 1},
            "'channel' = 'mag_x'",
        ),
        (
            {"kind": "bias_step", "channel": "gyro_x", "magnitude": 1},
            "'start_s' or 'start_sample' is required",
        ),
        (
            {
                "kind": "bias_step",
                "channel": "gyro_x",
                "start_s": 1,
                "start_sample": 3,
                "magnitude": 1,
            },
            "not both",
        ),
        ({"kind": "bias_step", "channel": "gyro_x", "start_s": -1, "magnitude": 1}, "out of range"),
        (
            {"kind": "bias_step", "channel": "gyro_x", "start_sample": 1.5, "magnitude": 1},
            "not a whole number",
        ),
        ({"kind": "bias_step", "channel": "gyro_x", "start_s": 0}, "'magnitude' is required"),
        (
            {"kind": "bias_step", "channel": "gyro_x", "start_s": 0, "magnitude": float("nan")},
            "not a finite number",
        ),
        (
            {"kind": "stuck_at", "channel": "gyro_x", "start_s": 0, "magnitude": 2},
            "takes no 'magnitude'",
        ),
        (
            {"kind": "scale_step", "channel": "gyro_x", "start_s": 0, "magnitude": -2},
            "'magnitude' = -2.0 is out of range: allowed [-1.0, 10.0] -",
        ),
        (
            {"kind": "saturation", "channel": "accel_y", "start_s": 0, "magnitude": 0},
            "allowed (0.0, inf) m/s^2",
        ),
        (
            {"kind": "noise_burst", "channel": "gyro_x", "start_s": 0, "magnitude": 0.5},
            "out of range",
        ),
        (
            {"kind": "spikes", "channel": "gyro_x", "start_s": 0, "magnitude": 1},
            "'rate_hz' = None is out of range: allowed (0, 200.0] Hz",
        ),
        (
            {"kind": "bias_step", "channel": "gyro_x", "start_s": 0, "magnitude": 1, "rate_hz": 3},
            "spikes' faults only",
        ),
        (
            {
                "kind": "bias_step",
                "channel": "gyro_x",
                "start_s": 0,
                "magnitude": 1,
                "permanent": True,
                "duration_s": 1,
            },
            "a permanent fault has no 'duration_s'",
        ),
        (
            {
                "kind": "bias_step",
                "channel": "gyro_x",
                "start_s": 0,
                "magnitude": 1,
                "permanent": False,
            },
            "'duration_s' or 'duration_samples' is required",
        ),
        (
            {
                "kind": "bias_step",
                "channel": "gyro_x",
                "start_s": 0,
                "magnitude": 1,
                "duration_s": 0.001,
            },
            "less than one sample",
        ),
        (
            {
                "kind": "bias_step",
                "channel": "gyro_x",
                "start_s": 0,
                "magnitude": 1,
                "colour": "red",
            },
            "unknown key 'colour'",
        ),
        ("bias_step", "expected a mapping"),
    ],
)
def test_each_mistake_is_one_line_naming_entry_and_field(entry, words):
    with pytest.raises(FaultScheduleError) as err:
        parse({"kind": "sign_flip", "channel": "gyro_y", "start_s": 0}, entry)
    text = str(err.value)
    assert text.startswith("fault 1") and words in text and "\n" not in text, text


def test_document_shape():
    for doc in ([], {"faults": 3}, {"faults": [], "extra": 1}, "faults"):
        with pytest.raises(FaultScheduleError):
            parse_schedule(doc, CHANNELS, UNITS, FS)


def test_file_errors_name_the_file(tmp_path):
    good = tmp_path / "s.yaml"
    good.write_text("faults:\n  - {kind: sign_flip, channel: gyro_x, start_s: 1.0}\n")
    (e,) = load_schedule(good, CHANNELS, UNITS, FS)
    assert e.kind == "sign_flip" and e.first == 200
    bad = tmp_path / "bad.yaml"
    bad.write_text("faults:\n  - {kind: sign_flip, channel: gyro_x, start_s: [\n")
    alias = tmp_path / "alias.yaml"
    alias.write_text("a: &x 1\nfaults: *x\n")
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("faults:\n  - {kind: sign_flip, channel: gyro_q, start_s: 1.0}\n")
    for path, words in (
        (bad, "line"),
        (alias, "alias"),
        (wrong, "gyro_q"),
        (tmp_path / "none.yaml", "No such file"),
        (tmp_path, "Is a directory"),
    ):
        with pytest.raises(FaultScheduleError) as err:
            load_schedule(path, CHANNELS, UNITS, FS)
        text = str(err.value)
        assert text.startswith(f"fault schedule {str(path)!r}") and words in text, text
        assert "\n" not in text


def test_dropped_samples_act_on_the_whole_stream():
    a, b = parse(
        {"kind": "dropped_samples", "start_s": 0.1, "duration_samples": 5},
        {"kind": "dropped_samples", "start_sample": 22, "duration_s": 0.04},
    )
    assert (a.channel, a.channel_index, a.first, a.count, a.magnitude) == ("", -1, 20, 5, 0.0)
    assert (b.first, b.count) == (22, 8)
    # overlapping drops merge; blocks that hold none are delivered whole (None)
    assert delivered_runs((a, b), 0, 40) == [(0, 20), (30, 40)]
    assert delivered_runs((a, b), 24, 4) == []
    assert delivered_runs((a, b), 28, 10) == [(2, 10)]
    assert delivered_runs((a, b), 30, 10) is None
    for entry, words in (
        ({"channel": "gyro_x", "duration_samples": 5}, "no 'channel'"),
        ({}, "give 'duration_s' or 'duration_samples'"),
        ({"permanent": True}, "give 'duration_s' or 'duration_samples'"),
        ({"duration_samples": 5, "magnitude": 2}, "takes no 'magnitude'"),
    ):
        with pytest.raises(FaultScheduleError) as err:
            parse({"kind": "dropped_samples", "start_sample": 3, **entry})
        text = str(err.value)
        assert text.startswith("fault 0 (dropped_samples)") and words in text, text


def test_every_kind_is_listed_with_a_unit():
    assert FAULT_KINDS["dropped_samples"].family == "timing"
    assert {k for k, v in FAULT_KINDS.items() if v.family == "sensor"} == {
        "stuck_at",
        "bias_step",
        "bias_ramp",
        "scale_step",
        "noise_burst",
        "spikes",
        "saturation",
        "sign_flip",
    }


def test_temperature_step_is_offered_only_where_the_device_models_it():
    from mems_sim.hardware.fault_schedule import PHYSICAL_KINDS, physical_offset

    entry = {"kind": "temperature_step", "start_sample": 10, "magnitude": 5.0}
    with pytest.raises(FaultScheduleError, match="not a fault of this device"):
        parse(entry)
    kinds = {**FAULT_KINDS, **PHYSICAL_KINDS}
    a, b = parse_schedule(
        {"faults": [entry, {**entry, "start_sample": 12, "duration_samples": 2, "magnitude": -1}]},
        CHANNELS,
        UNITS,
        FS,
        kinds,
    )
    assert (a.channel, a.permanent, a.magnitude, a.unit) == ("", True, 5.0, "K")
    assert list(physical_offset((a, b), "temperature_step", 8, 8)) == [0, 0, 5, 5, 4, 4, 5, 5]
    assert physical_offset((a, b), "temperature_step", 0, 10) is None
    for bad, words in (
        ({"magnitude": 150.0}, "out of range"),
        ({"channel": "gyro_x"}, "no 'channel'"),
    ):
        with pytest.raises(FaultScheduleError, match=words):
            parse_schedule({"faults": [{**entry, **bad}]}, CHANNELS, UNITS, FS, kinds)
