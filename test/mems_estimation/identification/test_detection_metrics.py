"""Detection scores of window verdicts against labelled faults: detection and delay,
false-alarm episodes outside the faults and their guard, the two-sided test and the
magnitude at 95 % detection, on hand-built verdicts whose answers are counted by hand."""

import numpy as np
import pytest

from mems_estimation.identification.detection_metrics import (
    Fault,
    Verdicts,
    detection_curve,
    detections,
    false_alarms,
    magnitude_at,
)

W = 100


def verdicts(levels, low=None):
    k = len(levels)
    return Verdicts.of(np.arange(k) * W, np.full(k, W), levels, low)


def test_detected_by_the_first_alarming_window_within_the_horizon():
    v = verdicts([0, 0, 0, 1, 2, 0, 0, 0])
    a, c = detections([Fault(250, 450), Fault(610, 700)], v, horizon=200)
    # fault [250, 450): window 3 [300, 400) alarms and ends at 400 <= 250 + 200
    assert (a.detected, a.delay) == (True, 150)
    assert c.detected is False and c.delay is None
    (late,) = detections([Fault(250, 450)], v, horizon=149)
    assert late.detected is False  # the alarm's verdict comes at 400, after 250 + 149


def test_an_alarm_outside_the_faulty_samples_does_not_count():
    v = verdicts([0, 1, 0, 0, 0])
    (d,) = detections([Fault(300, 350)], v, horizon=1000)
    assert not d.detected
    (p,) = detections([Fault(300, None)], verdicts([0, 0, 0, 0, 1]), horizon=10_000)
    assert (p.detected, p.delay) == (True, 200)


def test_false_alarm_episodes_outside_faults_and_guard():
    # windows 0..9; fault [300, 350) with guard 100 covers windows 3 and 4 (up to 450)
    v = verdicts([1, 1, 0, 1, 1, 0, 1, 0, 2, 2])
    fa = false_alarms([Fault(300, 350)], v, guard=100)
    assert fa.windows == 8 and fa.samples == 800
    assert fa.alarm_windows == 5  # windows 0, 1, 6, 8, 9
    assert fa.episodes == 3  # (0, 1), (6), (8, 9)
    assert fa.per_window() == pytest.approx(5 / 8)
    assert fa.per_hour(1e6) == pytest.approx(3 / (800 / 1e6 / 3600))
    assert false_alarms([Fault(0, None)], v, guard=0).windows == 0


def test_two_sided_counts_low_windows():
    v = verdicts([0, 0, 0, 0], low=[False, False, True, False])
    f = [Fault(200, 300)]
    assert not detections(f, v, 500)[0].detected
    assert detections(f, v, 500, two_sided=True)[0].detected
    assert false_alarms([], v, 0, two_sided=True).alarm_windows == 1


def test_curve_and_magnitude_at_95_percent():
    from mems_estimation.identification.detection_metrics import Detection

    scores = [
        Detection(Fault(0, 1, "bias_step", m), hit, None)
        for m, hit in [(1, False), (1, False), (2, True), (2, False), (3, True), (3, True)]
    ]
    mags, p, n = detection_curve(scores)
    assert mags.tolist() == [1, 2, 3] and p.tolist() == [0, 0.5, 1] and n.tolist() == [2, 2, 2]
    assert magnitude_at(mags, p) == pytest.approx(2.9)
    assert magnitude_at(mags, [0, 0.5, 0.9]) is None
    assert magnitude_at(mags, [0.96, 1, 1]) == 1.0


def test_overlapping_or_unordered_windows_are_refused():
    with pytest.raises(ValueError, match="order"):
        Verdicts.of([0, 50], [100, 100], [0, 0])
    with pytest.raises(ValueError, match="one length"):
        Verdicts.of([0, 100], [100], [0, 0])
