"""ParamSpec ranges: inclusive and exclusive bounds, in the text and in validation."""

import pytest

from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.params import descriptor


def test_an_exclusive_maximum_is_refused_and_written_open():
    spec = ParamSpec(
        "alpha",
        1e-3,
        "-",
        "a probability",
        min=0.0,
        max=0.5,
        min_exclusive=True,
        max_exclusive=True,
    )
    assert spec.range_text() == "(0.0, 0.5) -"
    assert spec.validate(0.4999) == 0.4999
    for bad in (0.0, 0.5, 0.7):
        with pytest.raises(ParameterError, match=r"allowed \(0.0, 0.5\)"):
            spec.validate(bad)


def test_an_inclusive_maximum_is_allowed_and_written_closed():
    spec = ParamSpec("q", 1.0, "-", "a factor", min=0.0, max=2.0)
    assert spec.range_text() == "[0.0, 2.0] -"
    assert spec.validate(2.0) == 2.0
    with pytest.raises(ParameterError):
        spec.validate(2.0000001)


def test_an_exclusive_integer_maximum_narrows_the_ros_range():
    spec = ParamSpec("n", 3, "-", "a count", min=0, max=10, min_exclusive=True, max_exclusive=True)
    r = descriptor(spec).integer_range[0]
    assert (r.from_value, r.to_value) == (1, 9)
    with pytest.raises(ParameterError):
        spec.validate(10)
    assert spec.validate(9) == 9
