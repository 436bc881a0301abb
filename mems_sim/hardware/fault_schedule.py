"""A device's fault schedule: which fault, on which channel, from which sample, for how
long, how strong, read from a YAML file a user hands over and validated like every
parameter (unit, range, one-line errors).

File format (one mapping with a list ``faults``)::

    faults:
      - kind: bias_step        # one of FAULT_KINDS the device offers
        channel: gyro_z        # one of the device's channels
        start_s: 2.0           # sensor time after the device's first sample [s]
        duration_s: 0.5        # or duration_samples, or permanent: true (the default)
        magnitude: 0.01        # in the kind's unit (the channel's unit for a bias step)
      - kind: spikes
        channel: accel_x
        start_sample: 1000     # or a sample index
        duration_samples: 2000
        magnitude: 0.5         # spike amplitude [channel unit]
        rate_hz: 5.0           # mean spike rate [Hz] (spikes only)

A timing or physical fault acts on the whole device and names no channel::

      - kind: dropped_samples  # samples the device never delivers: a declared device gap
        start_s: 1.0
        duration_samples: 250
      - kind: temperature_step # a thermal shock: the device temperature steps [K]
        start_s: 5.0
        magnitude: 10.0        # permanent unless a duration is given

Times are in the device's own sample clock (``start_s * fs`` rounded to the nearest sample),
so a schedule means the same samples at any frame size and on any replay. Faults on one
channel may overlap; they act in the order of the file (:mod:`mems_sim.hardware.sensor_faults`).
The fault kinds are those of fault-injection practice for inertial sensors (stuck-at, bias
step and drift, scale-factor change, noise increase, spikes, saturation, sign inversion:
Hwang, Kim, Kim & Seah, "A survey of fault detection, isolation, and reconfiguration
methods", IEEE Trans. Control Syst. Technol. 18(3), 2010, Sec. II); dropped samples are
the data-acquisition overrun of a real part (a FIFO that overflows, a bus transfer lost).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import yaml

from mems_sim.bounded_yaml import load_file, problem
from mems_sim.params import ParameterError
from mems_sim.stream_index import DROPPED_SAMPLES, uncovered

#: Longest schedule accepted [entries]: each run may carry many faults, not millions.
MAX_FAULTS = 10_000
#: Keys of one schedule entry.
ENTRY_KEYS = frozenset(
    {
        "kind",
        "channel",
        "start_s",
        "start_sample",
        "duration_s",
        "duration_samples",
        "permanent",
        "magnitude",
        "rate_hz",
    }
)


@dataclass(frozen=True)
class FaultKind:
    """One kind of fault.

    Attributes:
        name: the schedule's ``kind``.
        family: ``"sensor"`` (acts on the converter input), ``"timing"`` or ``"physical"``.
        unit: unit of ``magnitude``; ``"channel"`` for the channel's own unit,
            ``"channel/s"`` for its unit per second, ``"-"`` for a ratio, ``""`` for none.
        description: one line: what the fault does.
        min: smallest magnitude (inclusive unless ``min_exclusive``), None for no bound.
        max: largest magnitude, None for no bound.
        min_exclusive: whether ``min`` itself is refused.
    """

    name: str
    family: str
    unit: str
    description: str
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False

    def unit_for(self, channel_unit: str) -> str:
        """The SI unit of the magnitude on a channel of unit ``channel_unit``."""
        if self.unit == "channel":
            return channel_unit
        if self.unit == "channel/s":
            return f"{channel_unit}/s"
        return self.unit

    def range_text(self, channel_unit: str) -> str:
        lo = "-inf" if self.min is None else repr(self.min)
        hi = "inf" if self.max is None else repr(self.max)
        left = "(" if (self.min is None or self.min_exclusive) else "["
        right = ")" if self.max is None else "]"
        return f"{left}{lo}, {hi}{right} {self.unit_for(channel_unit)}".rstrip()


#: Sensor faults: they act on the analog value the converter digitises.
SENSOR_KINDS: tuple[FaultKind, ...] = (
    FaultKind("stuck_at", "sensor", "", "output frozen at its value at the onset"),
    FaultKind("bias_step", "sensor", "channel", "constant offset added"),
    FaultKind("bias_ramp", "sensor", "channel/s", "offset growing at this rate from the onset"),
    FaultKind(
        "scale_step", "sensor", "-", "scale factor times (1 + magnitude)", min=-1.0, max=10.0
    ),
    FaultKind(
        "noise_burst",
        "sensor",
        "-",
        "white noise raised to magnitude times the channel's white-noise standard deviation",
        min=1.0,
        max=1.0e4,
    ),
    FaultKind(
        "spikes",
        "sensor",
        "channel",
        "single-sample spikes of this amplitude (random sign) at mean rate rate_hz",
    ),
    FaultKind(
        "saturation",
        "sensor",
        "channel",
        "output clipped at +-magnitude (a lowered rail)",
        min=0.0,
        min_exclusive=True,
    ),
    FaultKind("sign_flip", "sensor", "", "output inverted"),
)
#: Timing faults: they act on the device's sample stream, not on one channel.
TIMING_KINDS: tuple[FaultKind, ...] = (
    FaultKind(
        DROPPED_SAMPLES,
        "timing",
        "",
        "the samples are never delivered: a gap in the device's streams (its truth stays "
        "whole), declared on the faults topic as a device gap",
    ),
)
#: Physical faults: they act on the device's physics (offered by the devices that model
#: them: the temperature step by the IMU, whose model takes the temperature per sample).
PHYSICAL_KINDS: dict[str, FaultKind] = {
    "temperature_step": FaultKind(
        "temperature_step",
        "physical",
        "K",
        "the device temperature steps by this many kelvin (a thermal shock); its temperature "
        "sensor follows with its own lag",
        min=-100.0,
        max=100.0,
    ),
}
#: The timing kinds by name: the schedule of a device whose converter sits inside a loop
#: that has no sensor-fault injection yet (the sigma-delta resonator, the AMDM scanner).
TIMING_ONLY: dict[str, FaultKind] = {k.name: k for k in TIMING_KINDS}
#: Every kind by name (physical kinds join as the devices offer them).
FAULT_KINDS: dict[str, FaultKind] = {k.name: k for k in SENSOR_KINDS + TIMING_KINDS}
#: Every kind of every family by name (what a schedule entry's kind is looked up in).
ALL_KINDS: dict[str, FaultKind] = {**FAULT_KINDS, **PHYSICAL_KINDS}
#: Kinds whose magnitude is ignored (it must be absent or 0).
NO_MAGNITUDE = frozenset(k.name for k in ALL_KINDS.values() if k.unit == "")
#: Largest spike rate [Hz] relative to the sample rate (at most one spike per sample).
MAX_SPIKE_RATE_FRACTION = 1.0


@dataclass(frozen=True)
class FaultEntry:
    """One scheduled fault, in samples of the device's clock.

    Attributes:
        kind: a name of :data:`FAULT_KINDS`.
        channel: the channel's name ('' for a timing fault: the whole stream).
        channel_index: its position in the device's channel list, -1 for none, -.
        first: first faulty sample index, -.
        count: number of faulty samples, -; None when permanent.
        magnitude: in the kind's unit on that channel (:meth:`FaultKind.unit_for`).
        unit: that unit.
        rate_hz: spike rate of ``spikes`` [Hz], else 0.
        number: the entry's position in the schedule (0-based), -.
    """

    kind: str
    channel: str
    channel_index: int
    first: int
    count: int | None
    magnitude: float
    unit: str
    rate_hz: float = 0.0
    number: int = 0

    @property
    def permanent(self) -> bool:
        return self.count is None

    @property
    def end(self) -> int | None:
        """One past the last faulty sample, None when permanent."""
        return None if self.count is None else self.first + self.count

    def overlap(self, first: int, n: int) -> tuple[int, int]:
        """The faulty part ``[lo, hi)`` of the block of samples ``[first, first + n)``, as
        offsets into the block (``lo == hi`` when it holds none)."""
        lo = max(self.first, first)
        hi = first + n if self.count is None else min(self.first + self.count, first + n)
        if hi <= lo:
            return 0, 0
        return lo - first, hi - first


class FaultScheduleError(ValueError):
    """A schedule that cannot be used (one line, naming the entry and the field)."""


def _number(entry: Mapping, key: str, where: str) -> float | None:
    """A finite number under ``key`` (None when absent)."""
    if key not in entry:
        return None
    value = entry[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise FaultScheduleError(f"{where}: '{key}' = {value!r} is not a finite number")
    return float(value)


def _whole(entry: Mapping, key: str, where: str) -> int | None:
    """A whole number >= 0 under ``key`` (None when absent)."""
    value = _number(entry, key, where)
    if value is None:
        return None
    if not value.is_integer() or value < 0:
        raise FaultScheduleError(f"{where}: '{key}' = {entry[key]!r} is not a whole number >= 0")
    return int(value)


def _one_of(entry: Mapping, keys: tuple[str, str], where: str) -> str | None:
    """The one key of ``keys`` that ``entry`` has (None for neither); both is an error."""
    given = [k for k in keys if k in entry]
    if len(given) > 1:
        raise FaultScheduleError(f"{where}: give '{keys[0]}' or '{keys[1]}', not both")
    return given[0] if given else None


def _start(entry: Mapping, fs: float, where: str) -> int:
    """First faulty sample: ``start_sample``, or ``start_s`` at ``fs`` [Hz] rounded."""
    key = _one_of(entry, ("start_s", "start_sample"), where)
    if key is None:
        raise FaultScheduleError(f"{where}: 'start_s' or 'start_sample' is required")
    if key == "start_sample":
        return _whole(entry, key, where)
    t = _number(entry, key, where)
    if t < 0:
        raise FaultScheduleError(f"{where}: 'start_s' = {t!r} is out of range: allowed [0, inf) s")
    return int(round(t * fs))


def _count(entry: Mapping, fs: float, where: str) -> int | None:
    """Faulty samples (None: permanent) of ``duration_samples``/``duration_s``/``permanent``."""
    key = _one_of(entry, ("duration_s", "duration_samples"), where)
    permanent = entry.get("permanent", key is None)
    if not isinstance(permanent, bool):
        raise FaultScheduleError(f"{where}: 'permanent' = {permanent!r} is not true/false")
    if permanent:
        if key is not None:
            raise FaultScheduleError(f"{where}: a permanent fault has no '{key}'")
        return None
    if key is None:
        raise FaultScheduleError(f"{where}: 'duration_s' or 'duration_samples' is required")
    if key == "duration_samples":
        n = _whole(entry, key, where)
    else:
        d = _number(entry, key, where)
        if d <= 0:
            raise FaultScheduleError(
                f"{where}: 'duration_s' = {d!r} is out of range: allowed (0, inf) s"
            )
        n = int(round(d * fs))
    if n < 1:
        raise FaultScheduleError(f"{where}: the fault lasts less than one sample at {fs!r} Hz")
    return n


def _magnitude(entry: Mapping, kind: FaultKind, channel_unit: str, where: str) -> float:
    """The entry's magnitude, checked against the kind's range."""
    value = _number(entry, "magnitude", where)
    if kind.name in NO_MAGNITUDE:
        if value not in (None, 0.0):
            raise FaultScheduleError(f"{where}: a '{kind.name}' fault takes no 'magnitude'")
        return 0.0
    if value is None:
        raise FaultScheduleError(
            f"{where}: 'magnitude' is required ({kind.range_text(channel_unit)})"
        )
    low = kind.min is not None and (value <= kind.min if kind.min_exclusive else value < kind.min)
    if low or (kind.max is not None and value > kind.max):
        raise FaultScheduleError(
            f"{where}: 'magnitude' = {value!r} is out of range: allowed "
            f"{kind.range_text(channel_unit)}"
        )
    return value


def _rate(entry: Mapping, kind: FaultKind, fs: float, where: str) -> float:
    """``rate_hz`` of a spikes fault (required, in (0, fs]); refused on other kinds."""
    rate = _number(entry, "rate_hz", where)
    if kind.name != "spikes":
        if rate is not None:
            raise FaultScheduleError(f"{where}: 'rate_hz' belongs to 'spikes' faults only")
        return 0.0
    top = MAX_SPIKE_RATE_FRACTION * fs
    if rate is None or not (0.0 < rate <= top):
        raise FaultScheduleError(
            f"{where}: 'rate_hz' = {rate!r} is out of range: allowed (0, {top!r}] Hz"
        )
    return rate


def parse_entry(
    entry: object,
    number: int,
    channels: Sequence[str],
    units: Sequence[str],
    fs: float,
    kinds: Mapping[str, FaultKind] = FAULT_KINDS,
) -> FaultEntry:
    """One validated :class:`FaultEntry` from a schedule's ``faults[number]``.

    Args:
        entry: the YAML mapping.
        number: its position, for the messages.
        channels: the device's channel names; units: their SI units.
        fs: the device's sample rate [Hz].
        kinds: the kinds the device offers.
    Raises:
        FaultScheduleError: one line naming the entry and the field.
    """
    where = f"fault {number}"
    if not isinstance(entry, Mapping):
        raise FaultScheduleError(f"{where}: expected a mapping, got {type(entry).__name__}")
    unknown = sorted(str(k) for k in entry if k not in ENTRY_KEYS)
    if unknown:
        raise FaultScheduleError(
            f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(ENTRY_KEYS))})"
        )
    name = entry.get("kind")
    if name not in kinds:
        raise FaultScheduleError(
            f"{where}: 'kind' = {name!r} is not a fault of this device (one of: {', '.join(kinds)})"
        )
    kind = kinds[name]
    where = f"fault {number} ({name})"
    if kind.family in ("timing", "physical"):
        return _device_entry(entry, kind, number, fs, where)
    channel = entry.get("channel")
    if channel not in channels:
        raise FaultScheduleError(
            f"{where}: 'channel' = {channel!r} is not a channel of this device (one of: "
            f"{', '.join(channels)})"
        )
    index = list(channels).index(channel)
    return FaultEntry(
        kind=name,
        channel=channel,
        channel_index=index,
        first=_start(entry, fs, where),
        count=_count(entry, fs, where),
        magnitude=_magnitude(entry, kind, units[index], where),
        unit=kind.unit_for(units[index]),
        rate_hz=_rate(entry, kind, fs, where),
        number=number,
    )


def _device_entry(entry: Mapping, kind: FaultKind, number: int, fs: float, where: str):
    """A timing or physical fault: the whole device (no channel); a timing fault for a
    stated duration."""
    if "channel" in entry:
        raise FaultScheduleError(
            f"{where}: a {kind.family} fault acts on the whole device: no 'channel'"
        )
    count = _count(entry, fs, where)
    if count is None and kind.family == "timing":
        raise FaultScheduleError(
            f"{where}: give 'duration_s' or 'duration_samples' (a device that never delivers "
            "again is a shorter run: set its duration)"
        )
    return FaultEntry(
        kind=kind.name,
        channel="",
        channel_index=-1,
        first=_start(entry, fs, where),
        count=count,
        magnitude=_magnitude(entry, kind, "", where),
        unit=kind.unit_for(""),
        number=number,
    )


def physical_offset(entries: Sequence[FaultEntry], kind: str, first: int, n: int):
    """The sum of the magnitudes of the ``kind`` entries of ``entries`` on each sample of
    ``[first, first + n)`` (e.g. the temperature step [K]), shape (n,); None when none
    overlaps the block."""
    out = None
    for e in entries:
        if e.kind != kind:
            continue
        lo, hi = e.overlap(first, n)
        if hi > lo:
            if out is None:
                out = np.zeros(n)
            out[lo:hi] += e.magnitude
    return out


def delivered_runs(
    entries: Sequence[FaultEntry], first: int, n: int
) -> list[tuple[int, int]] | None:
    """The parts ``[lo, hi)`` (offsets into the block) of the samples ``[first, first + n)``
    that the device delivers, in order, when ``dropped_samples`` entries of ``entries``
    overlap the block; None when none does (the whole block is delivered)."""
    cuts = [e.overlap(first, n) for e in entries if e.kind == DROPPED_SAMPLES and e.count]
    cuts = [c for c in cuts if c[1] > c[0]]
    return uncovered(cuts, 0, n) if cuts else None


def parse_schedule(
    data: object,
    channels: Sequence[str],
    units: Sequence[str],
    fs: float,
    kinds: Mapping[str, FaultKind] = FAULT_KINDS,
) -> tuple[FaultEntry, ...]:
    """The validated entries of a schedule document (``{"faults": [...]}``), in file order."""
    if not (isinstance(fs, (int, float)) and math.isfinite(fs) and fs > 0):
        raise ParameterError(f"sample rate {fs!r} Hz is invalid: must be > 0")
    if len(channels) != len(units):
        raise ValueError("one unit per channel")
    if not isinstance(data, Mapping) or set(data) != {"faults"}:
        raise FaultScheduleError("a fault schedule is a mapping with one key, 'faults'")
    entries = data["faults"]
    if entries is None:
        return ()
    if not isinstance(entries, list):
        raise FaultScheduleError("'faults' must be a list of fault entries")
    if len(entries) > MAX_FAULTS:
        raise FaultScheduleError(f"{len(entries)} faults: at most {MAX_FAULTS} per schedule")
    return tuple(parse_entry(e, k, channels, units, fs, kinds) for k, e in enumerate(entries))


def load_schedule(
    path: str | os.PathLike,
    channels: Sequence[str],
    units: Sequence[str],
    fs: float,
    kinds: Mapping[str, FaultKind] = FAULT_KINDS,
) -> tuple[FaultEntry, ...]:
    """The validated entries of the schedule file ``path`` (every bound of the project's
    bounded YAML reader applied). Raises :class:`FaultScheduleError` with one line
    starting with the path."""
    try:
        data = load_file(path)
    except OSError as exc:
        raise FaultScheduleError(f"fault schedule {str(path)!r}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise FaultScheduleError(f"fault schedule {str(path)!r}: {problem(exc)}") from None
    try:
        return parse_schedule(data, channels, units, fs, kinds)
    except FaultScheduleError as exc:
        raise FaultScheduleError(f"fault schedule {str(path)!r}: {exc}") from None
