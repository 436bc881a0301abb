"""A publisher's stall (:class:`~mems_sim.stream_index.PublicationStall`) on its own clock:
only after steady sending, beyond the timeout or three times its longest recent interval,
not after a declared device gap, and a clock stepped back is ignored."""

from __future__ import annotations

from mems_sim.stream_index import PublicationStall


def steady(watch: PublicationStall, start: float, period: float, n: int) -> float:
    """``n`` messages every ``period`` s from ``start``; the time of the last."""
    t = start
    for k in range(n):
        t = start + k * period
        assert watch.update(t) is None
    return t


def test_a_silence_beyond_the_timeout_after_steady_sending_is_a_stall():
    watch = PublicationStall(timeout=5.0)
    t = steady(watch, 100.0, 0.1, 20)
    assert watch.update(t + 10.0) == 10.0
    assert (watch.stalls, watch.longest_s) == (1, 10.0)
    # the stall is not one of the recent intervals: a second one is seen as well
    t = steady(watch, t + 10.1, 0.1, 5)
    assert watch.update(t + 6.0) == 6.0
    assert watch.stalls == 2 and watch.stalled_s == 16.0 and watch.longest_s == 10.0


def test_no_stall_before_steady_sending_nor_within_the_bound():
    watch = PublicationStall(timeout=5.0)
    t = steady(watch, 0.0, 0.1, PublicationStall.STEADY - 1)
    assert watch.update(t + 30.0) is None  # the 10th message: not steady before it
    assert watch.bound() == max(5.0, 3 * 30.0)
    slow = PublicationStall(timeout=5.0)
    t = steady(slow, 0.0, 4.0, 12)  # one message every 4 s: bound 12 s
    assert slow.bound() == 12.0
    assert slow.update(t + 11.0) is None  # within the bound: an interval, which widens it
    assert slow.bound() == 33.0
    assert slow.update(t + 11.0 + 34.0) == 34.0


def test_a_declared_device_gap_and_a_clock_stepped_back_are_no_stall():
    watch = PublicationStall(timeout=5.0)
    t = steady(watch, 0.0, 0.1, 20)
    assert watch.update(t + 20.0, declared=True) is None
    assert watch.update(t + 5.0) is None  # before the last message: ignored
    assert watch.update(t + 20.1) is None
    assert watch.stalls == 0
