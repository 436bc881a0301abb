"""Shared fixtures: localhost-only discovery, a private rclpy context per test."""

import itertools
import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("MPLBACKEND", "Agg")
# importing mems_sim pins numpy's and OpenBLAS's kernels (mems_sim.cpu_pins) before anything
# imports numpy, for a bare pytest too
from mems_sim.ros.env import apply_defaults

apply_defaults()

import pytest

_BASE = int(os.environ.get("ROS_DOMAIN_ID", "63"))
# pytest-xdist runs the suite in parallel worker processes (PYTEST_XDIST_WORKER=gw0, gw1, ...):
# worker i of n takes the domains i, i + n, i + 2n, ... so that no two workers share one.
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0)
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
_domains = itertools.count(0)
# The two tiers' domains: ``make test`` (ROS_DOMAIN_ID 63, odd) hands its tests 1..100
# without the Makefile's 61-65 and lets the runs they start without a domain (a campaign's
# run_scenario processes) lease 101..120; ``make acceptance`` (64, even) 121..210 and
# 211..232. Disjoint, so that a campaign's run never leases a domain a test of either tier
# is about to use; many, so that a domain comes round again only after the participants of
# a killed process on it have left discovery (Fast DDS's lease duration).
_ACCEPTANCE = _BASE % 2 == 0
_TEST_DOMAINS = (
    tuple(range(121, 211)) if _ACCEPTANCE else tuple(d for d in range(1, 101) if not 61 <= d <= 65)
)
os.environ["MEMS_FREE_DOMAINS"] = "211-232" if _ACCEPTANCE else "101-120"


def next_domain_id() -> int:
    """A domain id for one test, distinct from the other tests of this run, of the other
    xdist workers (worker i of n gets every n-th domain from the i-th), of a run of the
    other tier at the same time and of the runs the tests start without a domain (see
    ``MEMS_FREE_DOMAINS`` above)."""
    span = len(_TEST_DOMAINS) - len(_TEST_DOMAINS) % _WORKERS
    for _ in range(span // _WORKERS):  # skip a domain a scenario graph still leases
        domain = _TEST_DOMAINS[(_BASE * 7 * _WORKERS + _WORKER + _WORKERS * next(_domains)) % span]
        if _not_leased(domain):
            break
    return domain


def _not_leased(domain: int) -> bool:
    """True unless a scenario graph (of this process or another) holds ``domain``'s lease."""
    from mems_scenarios.domain import DomainLease

    lease = DomainLease.try_acquire(domain)
    if lease is None:
        return False
    lease.release()
    return True


@pytest.fixture(autouse=True)
def _no_domain_lease_left():
    """Every test ends the ROS domain leases it took: a lease left held (a graph not closed
    on a failure path) makes a later test on that domain refused as "in use"."""
    from mems_scenarios.domain import held_domains

    before = held_domains()
    yield
    left = sorted(held_domains() - before)
    assert not left, f"the test left the lease of ROS domain(s) {left} held"


@pytest.fixture
def domain_id():
    """A ROS domain id of this test's own."""
    return next_domain_id()


@pytest.fixture
def ros_context(domain_id):
    """An initialised rclpy context on a domain of its own, shut down after the test."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    yield ctx
    if ctx.ok():
        rclpy.shutdown(context=ctx)


@pytest.fixture
def subprocess_env(domain_id):
    """Environment for a console script started by a test: localhost, its own domain."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(domain_id)
    return env


@pytest.fixture
def cpu_hog():
    """One core busy for the duration of the test (a child process spinning)."""
    import subprocess
    import sys

    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    yield hog
    hog.kill()
    hog.wait()


def spin_until(executor, predicate, timeout=15.0):
    """Spin ``executor`` until ``predicate()`` holds or ``timeout`` s pass; return predicate()."""
    import time

    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return predicate()


def params(**kw):
    """rclpy parameter overrides from keyword arguments."""
    from rclpy.parameter import Parameter

    return [Parameter(k, value=v) for k, v in kw.items()]


@pytest.fixture
def graph(ros_context):
    """(context, executor, probe node) for tests that talk to nodes through real topics."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=ros_context)
    probe = rclpy.create_node("probe", context=ros_context)
    ex.add_node(probe)
    yield ros_context, ex, probe
    ex.shutdown()
