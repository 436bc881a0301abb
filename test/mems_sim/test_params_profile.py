"""Hardware profiles of a parameter table: ``ideal`` leaves it, ``realistic`` takes each
spec's real-part value."""

import pytest

from mems_sim.params import (
    HARDWARE_PROFILES,
    HARDWARE_SPEC,
    ParameterError,
    ParamSpec,
    profile_specs,
    resolve,
)

SPECS = (
    ParamSpec(
        "noise",
        0.0,
        "K",
        "white noise",
        "ideal: 0",
        min=0.0,
        max=1.0,
        realistic=0.01,
        realistic_source="datasheet",
    ),
    ParamSpec("gain", 2.0, "-", "a gain", "paper", min=0.0, max=10.0),
)


def test_ideal_is_the_table_itself():
    specs = profile_specs(SPECS, "ideal")
    assert all(a is b for a, b in zip(specs, SPECS, strict=True))


def test_realistic_takes_the_real_part_values_and_their_sources():
    noise, gain = profile_specs(SPECS, "realistic")
    assert (noise.default, noise.source) == (0.01, "datasheet")
    assert gain is SPECS[1]
    assert resolve(profile_specs(SPECS, "realistic")) == {"noise": 0.01, "gain": 2.0}
    assert resolve(profile_specs(SPECS, "realistic"), {"noise": 0.5})["noise"] == 0.5


def test_an_unknown_profile_is_refused_in_one_line():
    with pytest.raises(ParameterError, match="'ideal', 'realistic'") as exc:
        profile_specs(SPECS, "real")
    assert "\n" not in str(exc.value)
    assert HARDWARE_SPEC.choices == HARDWARE_PROFILES and HARDWARE_SPEC.default == "ideal"


def test_a_realistic_value_out_of_its_range_is_a_table_error():
    with pytest.raises(ValueError, match="realistic value of 'noise'"):
        ParamSpec("noise", 0.0, "K", "white noise", min=0.0, max=1.0, realistic=2.0)
