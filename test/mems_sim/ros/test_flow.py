"""The flow-control protocol (mems_sim.ros.flow): one progress, read in process from the
node and across processes from its ``~/progress``."""

from __future__ import annotations

from conftest import spin_until


def test_progress_is_the_largest_end_within_the_jump_and_follows_a_reset(graph):
    from mems_sim.ros.flow import ProgressReporter, ProgressSubscriber, progress_of

    _, ex, probe = graph
    import rclpy

    consumer = rclpy.create_node("consumer", namespace="/flow", context=graph[0])
    ex.add_node(consumer)
    consumer.progress_reporter = ProgressReporter(consumer, max_jump=1000)
    seen: list[int] = []
    remote = ProgressSubscriber(probe, "/flow/consumer", seen.append)
    assert remote.topic == "/flow/consumer/progress"
    assert progress_of(consumer) is None
    assert spin_until(ex, lambda: consumer.progress_reporter.publisher.get_subscription_count())
    rep = consumer.progress_reporter
    assert rep.report(100) == 100
    assert rep.report(50) == 100  # never backwards
    assert rep.report(5000) == 100  # a stray frame far away
    assert rep.report(10, follow=True) == 10  # a stream reset
    assert rep.report(600) == 600
    assert progress_of(consumer) == 600
    # depth 1: the subscriber is sure to get the last report (the latest progress)
    assert spin_until(ex, lambda: remote.value == 600)
    assert seen[-1] == 600 and remote.reports == len(seen)
    consumer.destroy_node()


def test_may_send_keeps_a_credit_of_samples():
    from mems_sim.ros.flow import may_send

    assert may_send(0, 100, None, 500)  # nothing sent yet
    assert may_send(400, 100, None, 500, start=0)
    assert not may_send(500, 100, None, 500, start=0)
    assert may_send(1400, 100, 1000, 500)
    assert not may_send(1500, 100, 1000, 500)
    assert may_send(900, 100, 1000, 0)  # at or before the progress: a repeat
