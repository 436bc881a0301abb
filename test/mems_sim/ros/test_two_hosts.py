"""A graph across two hosts: the device on one, its estimator and the recorder on the other.

The two hosts are two network namespaces joined by a veth pair (10.213.x.1 <-> .2/30),
nothing else in them (no route beyond the pair, only lo and the veth end): DDS carries the
graph over that link with discovery scoped to it (SUBNET range inside the namespaces,
the peer's address as a static peer, Fast DDS on UDPv4 only so that the shared-memory
transport, which the namespaces would share through /dev/shm, is not used). This is the
one documented exception to localhost-only discovery: no packet can leave the namespaces.

The recording must equal, message for message, the one of the same graph on one host
(localhost discovery). Needs CAP_NET_ADMIN (``ip netns add``); skipped with the reason
otherwise.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
NS = "/accelerometer"
TOPICS = [f"{NS}/{t}" for t in ("adc", "drive", "truth", "estimate")]
#: The device: 40 frames of 500 samples (0.02 s at 1 MHz), paced at 1/20 of real time
#: (50 frames/s): the graph, not the link, is what the test is about.
#: Stamps from 0 ('zero'): the two recordings are compared stamp for stamp.
DEVICE_PARAMS = dict(
    seed=7, frame_size=500, duration_s=0.02, realtime_factor=0.05, stamp_origin="zero"
)


def _netns_available() -> str | None:
    """None if network namespaces can be made here, else the reason."""
    if sys.platform != "linux":
        return "network namespaces need Linux"
    probe = f"mems_probe_{os.getpid()}"
    try:
        res = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    except FileNotFoundError:
        return "the ip command (iproute2) is not installed"
    if res.returncode != 0:
        return f"needs CAP_NET_ADMIN: ip netns add failed ({res.stderr.strip()})"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


_REASON = _netns_available()
# slow tier (make acceptance): 25-45 s of namespaces, discovery and two recordings
pytestmark = [pytest.mark.slow, pytest.mark.skipif(_REASON is not None, reason=_REASON or "")]


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@pytest.fixture
def two_hosts():
    """Two namespaces joined by a veth pair: ({'a': ns, 'b': ns}, {'a': ip, 'b': ip})."""
    tag = f"{os.getpid() % 10000}"
    names = {"a": f"mems_host_a_{tag}", "b": f"mems_host_b_{tag}"}
    net = 4 * (os.getpid() % 60)
    addrs = {
        "a": f"10.213.{net // 256}.{net % 256 + 1}",
        "b": f"10.213.{net // 256}.{net % 256 + 2}",
    }
    links = {"a": f"mva{tag}", "b": f"mvb{tag}"}
    try:
        for k in "ab":
            _ip("netns", "add", names[k])
        _ip(
            "link", "add", links["a"], "netns", names["a"], "type", "veth",
            "peer", "name", links["b"], "netns", names["b"],
        )  # fmt: skip
        for k in "ab":
            _ip("-n", names[k], "addr", "add", f"{addrs[k]}/30", "dev", links[k])
            _ip("-n", names[k], "link", "set", "lo", "up")
            _ip("-n", names[k], "link", "set", links[k], "up")
        yield names, addrs, links
    finally:
        for k in "ab":
            subprocess.run(["ip", "netns", "del", names[k]], capture_output=True)


def _env(domain_id: int, peer: str | None) -> dict:
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(HERE.parents[2])] + [p for p in [os.environ.get("PYTHONPATH")] if p]
    )
    for var in ("FASTDDS_DEFAULT_PROFILES_FILE", "MEMS_EMULATOR_FASTDDS_PROFILE"):
        env.pop(var, None)
    if peer is None:  # one host: the package's localhost-only graph
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    else:  # inside the test namespaces only: the link to the other host
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
        env["ROS_STATIC_PEERS"] = peer
        env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    return env


def _run_graph(tmp: Path, domain_id: int, hosts=None) -> tuple[Path, dict]:
    """Device (host a), estimator and recorder (host b); None: all on this host."""
    py = sys.executable
    out = tmp / ("two_hosts.mcap" if hosts else "one_host.mcap")
    # the device starts once the recorder and the estimator are matched and exits once
    # its frames are acknowledged (status 0)
    wait = f"{NS}/adc:2,{NS}/drive:2,{NS}/truth:1"
    lifecycle = dict(
        start_when_matched="true",
        min_subscribers=0,
        wait_for_subscribers=wait,
        exit_when_acknowledged="true",
    )
    params = [a for k, v in {**DEVICE_PARAMS, **lifecycle}.items() for a in ("-p", f"{k}:={v}")]
    cmds = {
        "recorder": [py, "-m", "mems_sim.bag.record_cli", "-o", str(out), *TOPICS],
        "estimator": [py, "-m", "mems_estimation.nodes.accelerometer_ekf_node"],
        "device": [py, "-m", "mems_sim.nodes.accelerometer_node", "--ros-args", *params],
    }
    procs, logs = {}, {}
    try:
        for name, cmd in cmds.items():
            where = "a" if name == "device" else "b"
            if hosts:
                names, addrs, _ = hosts
                peer = addrs["b" if where == "a" else "a"]
                cmd = ["ip", "netns", "exec", names[where], *cmd]
                env = _env(domain_id, peer)
            else:
                env = _env(domain_id, None)
            logs[name] = open(tmp / f"{out.stem}-{name}.log", "w+")
            procs[name] = subprocess.Popen(
                cmd, env=env, stdout=logs[name], stderr=subprocess.STDOUT, cwd=str(tmp)
            )
        procs["device"].wait(timeout=120)
        time.sleep(2.0)  # the last estimates reach the recorder
        for name in ("estimator", "recorder"):
            procs[name].send_signal(signal.SIGINT)
            procs[name].wait(timeout=60)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    texts = {}
    for name, f in logs.items():
        f.seek(0)
        texts[name] = f.read()
        f.close()
    assert procs["device"].returncode == 0, texts["device"][-2000:]
    assert procs["recorder"].returncode == 0, texts["recorder"][-2000:]
    return out, {"acked": procs["device"].returncode == 0}


def _messages(path: Path) -> dict[str, list]:
    from mems_sim.bag.player import read_messages

    got: dict[str, list] = {t: [] for t in TOPICS}
    for topic, _, log_time, msg in read_messages(str(path), TOPICS):
        got[topic].append((log_time, msg))
    return got


def _counters(ns: str, link: str) -> tuple[int, int]:
    res = subprocess.run(
        ["ip", "-n", ns, "-s", "-j", "link", "show", "dev", link],
        capture_output=True,
        text=True,
        check=True,
    )
    stats = json.loads(res.stdout)[0]["stats64"]
    return stats["tx"]["packets"], stats["rx"]["packets"]


def test_device_and_consumers_on_two_hosts_record_what_one_host_records(
    two_hosts, domain_id, tmp_path
):
    names, addrs, links = two_hosts
    one, dev_one = _run_graph(tmp_path, domain_id)
    two, dev_two = _run_graph(tmp_path, domain_id, two_hosts)
    assert dev_one["acked"]
    assert dev_two["acked"], "a subscriber on the other host did not acknowledge every frame"
    a, b = _messages(one), _messages(two)
    for topic in TOPICS:
        assert len(a[topic]) == 40, f"one host: {topic} has {len(a[topic])} of 40 frames"
        assert len(b[topic]) == 40, f"two hosts: {topic} has {len(b[topic])} of 40 frames"
        for k, ((ta, ma), (tb, mb)) in enumerate(zip(a[topic], b[topic])):
            assert ta == tb and ma == mb, f"{topic}: message {k} differs"
    # the data went over the pair, and the namespaces route nowhere else
    tx_a, rx_a = _counters(names["a"], links["a"])
    assert tx_a > 0 and rx_a > 0
    for k in "ab":
        routes = subprocess.run(
            ["ip", "-n", names[k], "route", "show"], capture_output=True, text=True, check=True
        ).stdout
        assert "default" not in routes and routes.count("\n") == 1, routes
        up = subprocess.run(
            ["ip", "-n", names[k], "-o", "link", "show"], capture_output=True, text=True
        ).stdout
        assert sorted(line.split(":")[1].strip().split("@")[0] for line in up.splitlines()) == (
            sorted(["lo", links[k]])
        )
