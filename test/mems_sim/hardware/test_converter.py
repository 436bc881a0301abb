"""Tests of the converter's static-error model (mems_sim.hardware.converter), no ROS.

The code-density (histogram) test of IEEE Std 1241-2010 on a 12-bit setting measures DNL
and INL from the hits per code of a linear input and compares them with the configured
transition table; the other tests check missing codes, the ideal converter against the
devices' quantiser, offset and gain in closed form, and parameter validation.
"""

import math

import numpy as np
import pytest

from mems_sim.devices.imu import IMU_SPECS, quantize
from mems_sim.hardware.converter import ADC_SPECS, Converter, code_range, inl_bow
from mems_sim.params import ParameterError

BITS = 12
#: Test setting: a 12-bit part with datasheet-limit nonlinearity, a small offset and gain.
SETTING = {
    "bits": BITS,
    "full_scale": 1.0,
    "offset_lsb": 0.3,
    "gain_error": 2e-3,
    "inl_peak_lsb": 1.0,
    "dnl_sd_lsb": 0.15,
    "seed": 7,
}
#: Ramp samples per LSB of input (up and down ramp together).
RAMP_DENSITY = 2 * 1201


def span_lsb(conv: Converter) -> tuple[float, float]:
    """The tests' input span [LSB]: 3 LSB beyond the outer transitions of both end codes."""
    return conv.code_min - 3.5, conv.code_max + 3.5


def triangle_lsb(conv: Converter, density: int) -> np.ndarray:
    """One period of a slow triangle [LSB of input] overdriving both end codes by 3 LSB:
    the up ramp at steps of 2/density, the down ramp half a step between them."""
    lo, hi = span_lsb(conv)
    step = 2.0 / density
    n = int(math.ceil((hi - lo) / step))
    up = lo + step * np.arange(n)
    return np.concatenate((up, (up + 0.5 * step)[::-1]))


def hits(conv: Converter, u_lsb: np.ndarray) -> np.ndarray:
    """Hits per code, index 0 = code_min, of inputs u [LSB]."""
    codes = conv.convert(u_lsb * conv.lsb)
    return np.bincount(codes.astype(np.int64) - conv.code_min, minlength=2**conv.bits)


def code_density(h: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Measured DNL of the interior codes and INL at their transitions from hits per code,
    IEEE Std 1241-2010 linear histogram: DNL[k] = h[k]/h_mean - 1 over the interior codes
    (the end codes are open), INL[k] = sum of DNL below k (INL = 0 at the first transition).

    Returns:
        (dnl (2^N - 2,), inl (2^N - 1,), h_mean).
    """
    inner = h[1:-1].astype(float)
    h_mean = math.fsum(inner) / inner.size
    dnl = inner / h_mean - 1.0
    inl = np.concatenate(([0.0], np.cumsum(dnl)))
    return dnl, inl, h_mean


def counting_sigma(conv: Converter, total: float, h_mean: float) -> tuple[np.ndarray, np.ndarray]:
    """Multinomial counting uncertainty of the measured DNL and INL, given ``total`` interior
    hits shared by the configured widths: sd(h_k) = sqrt(total p_k (1 - p_k)), and the
    cumulative count below transition k is binomial with F_k = sum_{j<k} p_j."""
    w = conv.widths_lsb
    p = w / math.fsum(w)
    f = np.concatenate(([0.0], np.cumsum(p)))
    sd_dnl = np.sqrt(total * p * (1.0 - p)) / h_mean
    sd_inl = np.sqrt(total * np.clip(f * (1.0 - f), 0.0, None)) / h_mean
    return sd_dnl, sd_inl


@pytest.fixture(scope="module")
def part() -> Converter:
    return Converter(SETTING)


# ------------------------------------------------------------------ 1. code density
def test_code_density_of_a_slow_triangle_measures_the_configured_dnl_and_inl(part):
    """Every interior code gets >= 1000 hits; every measured DNL and INL is within 3 sd of
    the counting uncertainty of the configured one, and, the ramp being deterministic,
    within its resolution of 2 hits (one per ramp) of it."""
    h = hits(part, triangle_lsb(part, RAMP_DENSITY))
    dnl, inl, h_mean = code_density(h)
    assert h[1:-1].min() >= 1000
    sd_dnl, sd_inl = counting_sigma(part, h[1:-1].sum(), h_mean)
    ref_inl = part.inl - part.inl[0]
    z_dnl = np.abs(dnl - part.dnl) / sd_dnl
    assert z_dnl.max() <= 3.0
    inner = slice(1, -1)  # the end transitions have F = 0 or 1: no counting uncertainty
    assert (np.abs(inl - ref_inl)[inner] / sd_inl[inner]).max() <= 3.0
    assert abs(inl[-1] - ref_inl[-1]) < 1e-9 and abs(ref_inl[-1]) < 1e-9
    resolution = 2.0 / h_mean
    assert np.abs(dnl - part.dnl).max() <= 2 * resolution
    assert np.abs(inl - ref_inl).max() <= 2 * resolution
    # the configured pattern is not trivial: the comparison could fail
    assert 0.1 < part.dnl.std() < 0.2 and 0.6 < np.abs(part.inl).max() < 2.0


def test_code_density_of_a_uniform_input_is_within_counting_statistics(part):
    """Random uniform input: the DNL z-scores are standard normal (mean 0, sd 1, 0.27 % of
    the codes beyond 3 sd expected; at most 1 % allowed, none beyond 5 sd); INL z-scores
    within 4 sd (they are strongly correlated: a bridge, not 4095 independent draws)."""
    lo, hi = span_lsb(part)
    rng = np.random.default_rng(20261202)
    u = rng.uniform(lo, hi, size=(2**BITS) * 1100)
    h = hits(part, u)
    dnl, inl, h_mean = code_density(h)
    assert h[1:-1].min() >= 400  # the narrowest code (DNL -0.54) of 1100 hits per LSB
    sd_dnl, sd_inl = counting_sigma(part, h[1:-1].sum(), h_mean)
    z = (dnl - part.dnl) / sd_dnl
    assert abs(z.mean()) < 0.1 and 0.9 < z.std() < 1.1
    assert np.mean(np.abs(z) > 3.0) <= 0.01 and np.abs(z).max() < 5.0
    inner = slice(1, -1)
    z_inl = (inl - (part.inl - part.inl[0]))[inner] / sd_inl[inner]
    assert np.abs(z_inl).max() < 4.0


def test_dnl_and_inl_follow_the_standard_definitions(part):
    """DNL[k] = G W[k]/Q - 1, INL[k] = sum of DNL below k (+ INL at the first transition);
    the total interior width is preserved: the first and last transitions are ideal."""
    g = 1.0 + SETTING["gain_error"]
    w = np.diff(part.transitions_lsb)
    np.testing.assert_allclose(part.dnl, g * w - 1.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(part.inl[1:] - part.inl[0], np.cumsum(part.dnl), atol=1e-9)
    assert abs(part.inl[0]) < 1e-12 and abs(part.inl[-1]) < 1e-9
    np.testing.assert_allclose(
        part.transitions, part.transitions_lsb * part.lsb, rtol=1e-15, atol=0
    )


@pytest.mark.parametrize("shape", ["parabola", "cubic"])
def test_the_inl_bow_has_its_configured_peak(shape):
    """dnl_sd = 0: the INL is the bow alone, zero at both ends, peak +1.5 LSB (the parabola
    at mid-scale, the cubic at s = 1/sqrt(3) with -1.5 LSB at s = -1/sqrt(3))."""
    conv = Converter({"bits": 10, "inl_peak_lsb": 1.5, "inl_shape": shape, "dnl_sd_lsb": 0.0})
    inl = conv.inl
    assert inl[0] == 0.0 and abs(inl[-1]) < 1e-12
    assert abs(inl.max() - 1.5) < 1e-5
    s = np.linspace(-1.0, 1.0, inl.size)
    if shape == "parabola":
        assert abs(s[np.argmax(inl)]) < 2.0 / inl.size and inl.min() >= 0.0
    else:
        assert abs(inl.min() + 1.5) < 1e-5
        assert abs(s[np.argmax(inl)] - 1 / math.sqrt(3)) < 2.0 / inl.size
    np.testing.assert_array_equal(inl_bow(5, 2.0, "parabola"), [0.0, 1.5, 2.0, 1.5, 0.0])


# ------------------------------------------------------------------ 2. missing codes
def test_configured_missing_codes_get_no_hits():
    """5 seeded missing codes and an explicit run of two and a lone code: zero hits; the
    neighbours take their width, half each; every other code is populated."""
    conv = Converter({**SETTING, "missing_codes": 5}, missing=[100, 101, -7])
    missing = conv.missing_codes
    assert len(missing) == 8 and {100, 101, -7} <= set(missing)
    h = hits(conv, triangle_lsb(conv, RAMP_DENSITY))
    idx = np.array(missing) - conv.code_min
    assert np.all(h[idx] == 0)
    others = np.setdiff1d(np.arange(1, h.size - 1), idx)
    assert h[others].min() >= 1000
    np.testing.assert_array_equal(conv.zero_width_codes(), missing)
    # the width of code -7 went to -8 and -6, half each
    base = Converter(SETTING).widths_lsb
    got = conv.widths_lsb
    k = -7 - conv.code_min - 1
    assert got[k - 1] == pytest.approx(base[k - 1] + base[k] / 2, abs=1e-12)
    assert got[k + 1] == pytest.approx(base[k + 1] + base[k] / 2, abs=1e-12)
    assert Converter({**SETTING, "missing_codes": 5}).missing_codes == tuple(
        c for c in missing if c not in (100, 101, -7)
    )


def test_a_code_is_made_missing_and_present_again_at_run_time(part):
    """set_missing makes code 1234 (and 0) missing: zero hits, only the neighbours' counts
    change; clearing restores the transition table and the hits bit for bit."""
    conv = Converter(SETTING)
    u = triangle_lsb(conv, 2 * 301)
    table = conv.transitions_lsb
    before = hits(conv, u)
    conv.set_missing([1234, 0])
    assert conv.missing_codes == (0, 1234)
    during = hits(conv, u)
    for c in (1234, 0):
        i = c - conv.code_min
        assert before[i] > 300 and during[i] == 0
        assert during[i - 1] + during[i + 1] == before[i - 1] + before[i] + before[i + 1]
    changed = np.flatnonzero(during != before) + conv.code_min
    assert set(changed) <= {1233, 1234, 1235, -1, 0, 1}
    conv.set_missing([1234], missing=False)
    assert conv.missing_codes == (0,)
    conv.clear_missing()
    assert conv.missing_codes == ()
    np.testing.assert_array_equal(conv.transitions_lsb, table)
    np.testing.assert_array_equal(hits(conv, u), before)


# ------------------------------------------------------------------ 3. the device quantiser
def _imu_lsb() -> float:
    return next(s.default for s in IMU_SPECS if s.name == "gyro_lsb")


@pytest.mark.parametrize("lsb", [_imu_lsb(), 2.0**-10])
def test_ideal_converter_equals_the_imu_quantiser_bit_for_bit(lsb):
    """mems_sim.devices.imu.quantize (np.rint, half to even, clipped to the 14-bit two's-
    complement range, saturation flags) against Converter.ideal: random inputs over twice
    the range, every exact tie k + 1/2 (lsb 2^-10 makes x/lsb exact), their float
    neighbours, the range ends and +-inf."""
    bits = 14
    conv = Converter.ideal(bits, lsb)
    lo, hi = code_range(bits)
    rng = np.random.default_rng(3)
    ties = (np.arange(lo - 3, hi + 4) + 0.5) * lsb
    x = np.concatenate(
        (
            rng.uniform(2 * lo, 2 * hi, 200_000) * lsb,
            ties,
            np.nextafter(ties, np.inf),
            np.nextafter(ties, -np.inf),
            np.array([0.0, -0.0, np.inf, -np.inf, lo * lsb, hi * lsb, 1e300, -1e300]),
        )
    )
    want_codes, want_sat = quantize(x, lsb, bits)
    codes, sat = conv.quantize(x)
    assert codes.dtype == want_codes.dtype == np.int32
    np.testing.assert_array_equal(codes, want_codes)
    np.testing.assert_array_equal(sat, want_sat)
    assert 0 < want_sat.sum() < x.size
    grid = conv.quantize(x[:700].reshape(-1, 7))[0]  # the shape is kept
    np.testing.assert_array_equal(grid, want_codes[:700].reshape(-1, 7))


# ------------------------------------------------------------------ 4. offset and gain
def test_offset_and_gain_shift_and_scale_the_transfer_in_closed_form():
    """Only offset 2.75 LSB and gain error +1.23 %: T[k]/Q = (k - 1/2 - offset)/G exactly,
    and away from the transitions code = clip(round(G x/Q + offset)); the transfer's
    least-squares line over the unclipped codes has slope G and intercept offset."""
    os_lsb, g_err = 2.75, 0.0123
    p = {"bits": BITS, "offset_lsb": os_lsb, "gain_error": g_err}
    conv = Converter({**p, "inl_peak_lsb": 0.0, "dnl_sd_lsb": 0.0})
    g = 1.0 + g_err
    np.testing.assert_array_equal(conv.transitions_lsb, (conv.codes - 0.5 - os_lsb) / g)
    lo, hi = conv.code_min, conv.code_max
    u = np.random.default_rng(5).uniform(lo - 10, hi + 10, 100_000)
    y = g * u + os_lsb
    clear = np.abs(y - np.floor(y) - 0.5) > 1e-6
    want = np.clip(np.rint(y), lo, hi)
    codes = conv.convert(u * conv.lsb)
    np.testing.assert_array_equal(codes[clear], want[clear])
    inside = (codes > lo) & (codes < hi)
    slope, intercept = np.polyfit(u[inside], codes[inside], 1)
    assert slope == pytest.approx(g, abs=2e-5) and intercept == pytest.approx(os_lsb, abs=5e-3)
    # the offset and gain move the table, not the linearity
    np.testing.assert_allclose(conv.inl, 0.0, atol=1e-9)
    np.testing.assert_allclose(conv.dnl, 0.0, atol=1e-9)


def test_a_batch_spreads_offset_and_gain_within_the_datasheet_limits():
    """device_seed draws offset (+-3 LSB) and gain (+-5/4096) of one part, reproducibly;
    values the user sets stay; the nonlinearity does not spread."""
    parts = [Converter(device_seed=s) for s in range(20)]
    offsets = np.array([c.params["offset_lsb"] for c in parts])
    gains = np.array([c.params["gain_error"] for c in parts])
    assert np.all(np.abs(offsets) <= 3.0) and np.abs(offsets).max() > 1.0
    assert np.all(np.abs(gains) <= 5 / 4096) and len(set(gains)) == 20
    again = Converter(device_seed=3)
    np.testing.assert_array_equal(again.transitions_lsb, parts[3].transitions_lsb)
    assert Converter({"offset_lsb": 0.5}, device_seed=3).params["offset_lsb"] == 0.5
    assert len({c.params["inl_peak_lsb"] for c in parts}) == 1
    assert all(s.spread is not None for s in ADC_SPECS if s.name in ("offset_lsb", "gain_error"))


# ------------------------------------------------------------------ 5. validation, seeds
@pytest.mark.parametrize(
    "params, match",
    [
        ({"bits": 1}, "'bits' = 1 is out of range"),
        ({"bits": 12.5}, "'bits' = 12.5 is invalid"),
        ({"full_scale": 0.0}, "'full_scale' = 0.0 is out of range"),
        ({"dnl_sd_lsb": -0.1}, "'dnl_sd_lsb' = -0.1 is out of range"),
        ({"dnl_sd_lsb": 0.6}, "'dnl_sd_lsb' = 0.6 is out of range"),
        ({"gain_error": 0.2}, "'gain_error' = 0.2 is out of range"),
        ({"offset_lsb": float("nan")}, "'offset_lsb' = nan is invalid"),
        ({"inl_shape": "sine"}, "'inl_shape' = 'sine' is invalid"),
        ({"bits": 4, "missing_codes": 15}, "4-bit converter has 14 interior codes"),
        ({"volts": 1.0}, "unknown parameter 'volts'"),
    ],
)
def test_out_of_range_parameters_raise(params, match):
    with pytest.raises(ParameterError, match=match):
        Converter(params)


def test_invalid_missing_codes_raise():
    lo, hi = code_range(BITS)
    for bad in (lo, hi, hi + 1, 1.5, True):
        with pytest.raises(ParameterError, match="interior codes"):
            Converter({"bits": BITS}, missing=[bad])
    conv = Converter({"bits": BITS})
    with pytest.raises(ParameterError, match=f"missing code {lo}"):
        conv.set_missing([lo])
    assert conv.missing_codes == ()
    with pytest.raises(ParameterError, match="'full_scale' = -8.0 is out of range"):
        Converter.ideal(4, -1.0)


def test_the_same_seed_gives_the_same_pattern_bit_for_bit():
    a = Converter({**SETTING, "missing_codes": 3})
    b = Converter({**SETTING, "missing_codes": 3})
    c = Converter({**SETTING, "missing_codes": 3, "seed": 8})
    assert a.dnl.tobytes() == b.dnl.tobytes() and a.missing_codes == b.missing_codes
    assert a.transitions_lsb.tobytes() == b.transitions_lsb.tobytes()
    assert not np.array_equal(a.dnl, c.dnl) and a.missing_codes != c.missing_codes
    assert abs(np.corrcoef(a.dnl, c.dnl)[0, 1]) < 0.1


def test_an_input_on_a_missing_code_s_collapsed_transitions_never_reads_it():
    """Code 5 missing: T[5] = T[6] = 5.0 LSB, an input of exactly 5 LSB reads 6 (the even
    neighbour); codes 5 and 6 missing: T[5..7] = 5.5 LSB reads 4 (7 is odd)."""
    conv = Converter.ideal(8, 1.0)
    conv.set_missing([5])
    assert conv.convert(np.array([5.0, np.nextafter(5.0, 0.0)])).tolist() == [6, 4]
    conv.set_missing([6])
    assert conv.convert(np.array([5.5, np.nextafter(5.5, 9.0)])).tolist() == [4, 7]
