"""The loss taxonomy of :mod:`mems_sim.stream_index`: every class of loss, for an
estimator's stream (repeats and reorders dropped), for a recording (every frame kept) and
for publisher sequence numbers; the missing head, declared device gaps and the stall timer."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from mems_sim import stream_index as si
from mems_sim.stream_index import (
    DEVICE_GAP,
    FIRST,
    GAP,
    NEXT,
    OUT_OF_ORDER,
    REPEAT,
    RESET,
    FramePairer,
    SequenceIndex,
    StallTimer,
    StreamIndex,
)


def test_the_module_imports_no_ros():
    tree = ast.parse(Path(si.__file__).read_text())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not {m for m in names if m.split(".")[0] in ("rclpy", "mems_msgs", "std_msgs")}


def test_an_estimator_stream_classes_and_counts_every_kind():
    s = StreamIndex(max_gap=1000, start=0)
    events = [
        s.update(0, 10),  # first
        s.update(10, 10),  # next
        s.update(10, 10),  # repeat: dropped
        s.update(520, 10),  # gap of 500
        s.update(500, 10),  # behind, never taken: out of order
        s.update(530 + 1001, 10),  # beyond max_gap: reset
    ]
    assert events == [
        (FIRST, 0),
        (NEXT, 0),
        (REPEAT, 0),
        (GAP, 500),
        (OUT_OF_ORDER, 0),
        (RESET, 1001),
    ]
    assert (s.repeats, s.out_of_order, s.gaps, s.missing_samples, s.resets) == (1, 1, 1, 500, 1)
    assert s.frames == 4 and s.samples == 40  # the taken frames only
    assert s.expected == 1541 and s.ahead
    assert s.update(0, 10) == (RESET, 0) and not s.ahead  # back by more than max_gap


def test_a_restart_inside_max_gap_takes_three_consecutive_frames():
    s = StreamIndex(max_gap=10**6)
    for k in range(100):
        s.update(1000 + 10 * k, 10)
    assert [s.update(10 * k, 10)[0] for k in range(3)] == [OUT_OF_ORDER] * 2 + [RESET]
    assert s.update(30, 10) == (NEXT, 0)
    # three behind frames that do not follow one another stay out of order
    t = StreamIndex(max_gap=10**6)
    t.update(1000, 10)
    assert [t.update(f, 10)[0] for f in (0, 100, 200)] == [OUT_OF_ORDER] * 3


def test_a_recording_keeps_every_frame_and_counts_anything_behind_as_a_reset():
    s = StreamIndex.recording(start=0)
    assert s.update(0, 10) == (FIRST, 0)
    assert s.update(10, 10) == (NEXT, 0)
    assert s.update(10, 10) == (RESET, 0)  # a repeat restarts a recording's accounting
    assert s.expected == 20
    assert s.update(2**40, 10) == (GAP, 2**40 - 20)  # no jump is too large to be a gap
    assert (s.gaps, s.resets, s.frames, s.samples) == (1, 1, 4, 40)
    assert s.repeats == s.out_of_order == 0


def test_missing_head_of_a_recording_that_started_late():
    s = StreamIndex.recording(start=0)
    assert s.missing_head == 0  # nothing seen yet
    s.update(300, 10)
    assert s.missing_head == 300 and s.first == 300
    assert StreamIndex().missing_head == 0  # unknown start: none counted
    q = SequenceIndex()
    for n in (4, 5, 6):
        q.update(n)
    assert q.missing_head == 3 and q.first == 4 and q.last == 6


def test_sequence_numbers_gap_and_reset():
    q = SequenceIndex()
    for n in (1, 2, 5, 6, 6, 3):
        q.update(n)
    assert (q.gaps, q.missing_messages, q.resets, q.messages, q.last) == (1, 2, 2, 6, 3)


def test_a_declared_device_gap_is_counted_apart_from_transport_loss():
    s = StreamIndex(max_gap=1000, start=0)
    s.update(0, 10)
    s.declare_device_gap(10, 40)
    assert s.update(50, 10) == (DEVICE_GAP, 40)  # every missing sample declared
    assert (s.gaps, s.missing_samples, s.device_gaps, s.device_missing_samples) == (0, 0, 1, 40)
    # partly declared: the rest is transport loss; the event says a transport gap
    s.declare_device_gap(60, 10)
    assert s.update(100, 10) == (GAP, 40)
    assert (s.gaps, s.missing_samples, s.device_gaps, s.device_missing_samples) == (1, 30, 2, 50)
    # a declaration of samples the stream delivered changes nothing
    s.declare_device_gap(0, 5)
    assert s.update(130, 10) == (GAP, 20) and s.device_missing_samples == 50


def test_a_declaration_after_its_jump_counts_the_transport_gap_again():
    """The declaration travels on another topic and may come after the jump: the samples
    of the transport gap it covers move to the device gap, each once."""
    s = StreamIndex.recording(start=0)
    s.update(0, 10)
    assert s.update(50, 10) == (GAP, 40)
    s.declare_device_gap(10, 40)
    assert (s.gaps, s.missing_samples, s.device_gaps, s.device_missing_samples) == (0, 0, 1, 40)
    s.declare_device_gap(10, 40)  # declared twice: counted once
    assert (s.gaps, s.missing_samples, s.device_gaps, s.device_missing_samples) == (0, 0, 1, 40)
    # a jump partly declared before it, the rest declared after it
    s.declare_device_gap(60, 10)
    assert s.update(100, 10) == (GAP, 40)
    assert (s.gaps, s.missing_samples, s.device_gaps, s.device_missing_samples) == (1, 30, 2, 50)
    s.declare_device_gap(80, 5)  # the middle of the rest: still one transport gap
    assert (s.gaps, s.missing_samples, s.device_gaps, s.device_missing_samples) == (1, 25, 2, 55)
    s.declare_device_gap(70, 30)
    assert (s.gaps, s.missing_samples, s.device_gaps, s.device_missing_samples) == (0, 0, 2, 80)
    # a late declaration beyond the stream also declares what is still to come
    assert s.update(110, 10) == (NEXT, 0)
    s.declare_device_gap(115, 30)
    assert s.update(145, 5) == (DEVICE_GAP, 25) and (s.gaps, s.device_gaps) == (0, 3)


def test_overlapping_declarations_count_each_sample_once():
    s = StreamIndex.recording(start=0)
    s.update(0, 10)
    s.declare_device_gap(10, 20)
    s.declare_device_gap(20, 20)
    s.declare_device_gap(15, 5)
    assert s.update(40, 10) == (DEVICE_GAP, 30) and s.device_missing_samples == 30


def test_stall_timer_on_the_callers_clock():
    t = StallTimer()
    assert not t.stalled(100.0, 1.0)  # not started
    t.touch(10.0)
    assert not t.stalled(11.0, 1.0) and t.stalled(11.5, 1.0)
    s = StreamIndex()
    s.update(0, 10, now=5.0)
    assert s.stalled(9.0, 3.0) and not s.stalled(7.0, 3.0)
    s.update(10, 10, now=8.5)
    assert not s.stalled(9.0, 3.0)


def test_pairer_needs_both_bounds_and_the_frame_size():
    p = FramePairer(("a", "b"), None, 2)
    assert p.add("a", 0, "x", 5) == [] and p.overflow == []
    assert p.add("b", 0, "y", 5) == [(0, "x", "y")]
    with pytest.raises(TypeError):
        p.add("a", 5, "x")  # the size is the caller's to give
