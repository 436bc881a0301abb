"""Local means local: the discovery range defaults (an empty range counts as LOCALHOST),
the localhost Fast DDS profile (valid for the installed Fast DDS, applied only when the
user configured nothing), no socket of a node process bound to 0.0.0.0 or a network
address, processes with and without the profile talking to each other, and no RTPS packet
on a network interface during a scenario run with an empty range."""

import ipaddress
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from conftest import spin_until
from proc_sockets import inet_sockets, is_loopback

from mems_sim.ros import env as ros_env

PROFILE = Path(__file__).resolve().parents[3] / "config" / ros_env.PROFILE_NAME
FASTDDS_XSD = Path(sys.prefix) / "share" / "fastdds" / "fastdds_profiles.xsd"
#: What a user's shell has: none of the variables apply_defaults sets in the test process.
SET_BY_DEFAULTS = (ros_env.PROFILE_VARIABLE, ros_env.MARKER_VARIABLE, ros_env.RANGE_VARIABLE)


def user_env(domain_id: int, **overrides: str) -> dict:
    """The environment of a process started from a user's shell, on its own domain."""
    env = {k: v for k, v in os.environ.items() if k not in SET_BY_DEFAULTS}
    env.update(ROS_DOMAIN_ID=str(domain_id), **overrides)
    return env


@pytest.fixture
def clean_env(monkeypatch):
    """os.environ without the variables apply_defaults reads or sets; the whole environment
    is restored afterwards (later tests of this process start ROS with it)."""
    saved = dict(os.environ)
    for name in (
        *SET_BY_DEFAULTS,
        "ROS_STATIC_PEERS",
        "ROS_DISCOVERY_SERVER",
        "RMW_IMPLEMENTATION",
        "SKIP_DEFAULT_XML_FILE",
    ):
        os.environ.pop(name, None)
    monkeypatch.chdir(tempfile.gettempdir())
    yield os.environ
    os.environ.clear()
    os.environ.update(saved)


# -- apply_defaults ---------------------------------------------------------------------


@pytest.mark.parametrize("value", [None, "", "LOCALHOST"])
def test_unset_empty_or_localhost_range_gets_the_localhost_profile(clean_env, value):
    if value is not None:
        clean_env[ros_env.RANGE_VARIABLE] = value
    ros_env.apply_defaults()
    assert Path(clean_env[ros_env.PROFILE_VARIABLE]).samefile(PROFILE)
    assert clean_env[ros_env.MARKER_VARIABLE] == clean_env[ros_env.PROFILE_VARIABLE]
    # rmw_fastrtps uses the profile as it is only outside its own LOCALHOST mode
    assert clean_env[ros_env.RANGE_VARIABLE] == "SYSTEM_DEFAULT"
    assert ros_env.localhost_only()


def test_apply_defaults_is_idempotent_and_follows_a_child_s_own_range(clean_env):
    ros_env.apply_defaults()
    first = dict(clean_env)
    ros_env.apply_defaults()
    assert dict(clean_env) == first
    # a child started with the parent's environment but LOCALHOST given again
    clean_env[ros_env.RANGE_VARIABLE] = "LOCALHOST"
    ros_env.apply_defaults()
    assert dict(clean_env) == first
    # a child given SUBNET: the inherited profile is dropped
    clean_env[ros_env.RANGE_VARIABLE] = "SUBNET"
    ros_env.apply_defaults()
    assert clean_env[ros_env.RANGE_VARIABLE] == "SUBNET"
    assert ros_env.PROFILE_VARIABLE not in clean_env
    assert ros_env.MARKER_VARIABLE not in clean_env
    assert not ros_env.localhost_only()


@pytest.mark.parametrize(
    "setting",
    [
        {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"},
        {"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"},
        {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT"},
    ],
)
def test_other_ranges_are_left_alone(clean_env, setting):
    clean_env.update(setting)
    ros_env.apply_defaults()
    assert clean_env[ros_env.RANGE_VARIABLE] == setting[ros_env.RANGE_VARIABLE]
    assert ros_env.PROFILE_VARIABLE not in clean_env


@pytest.mark.parametrize(
    "setting",
    [
        {"FASTDDS_DEFAULT_PROFILES_FILE": "/somewhere/my_profile.xml"},
        {"ROS_STATIC_PEERS": "192.0.2.7"},
        {"ROS_DISCOVERY_SERVER": "192.0.2.7:11811"},
        {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},
    ],
)
def test_a_user_configuration_keeps_rmw_s_localhost_mode(clean_env, setting):
    clean_env.update(setting)
    ros_env.apply_defaults()
    assert clean_env[ros_env.RANGE_VARIABLE] == "LOCALHOST"
    assert clean_env.get(ros_env.PROFILE_VARIABLE) == setting.get(ros_env.PROFILE_VARIABLE)
    assert ros_env.MARKER_VARIABLE not in clean_env


def test_a_profile_file_in_the_working_directory_keeps_rmw_s_localhost_mode(
    clean_env, tmp_path, monkeypatch
):
    (tmp_path / "DEFAULT_FASTDDS_PROFILES.xml").write_text("<dds/>")
    monkeypatch.chdir(tmp_path)
    ros_env.apply_defaults()
    assert clean_env[ros_env.RANGE_VARIABLE] == "LOCALHOST"
    assert ros_env.PROFILE_VARIABLE not in clean_env


def test_profile_is_valid_for_the_installed_fastdds():
    import xmlschema  # pinned in requirements.lock: a missing validator is a failure

    assert FASTDDS_XSD.is_file(), "the ros-fastdds wheel installs its XML schema there"
    xmlschema.XMLSchema(str(FASTDDS_XSD)).validate(str(PROFILE))


# -- ROS_DOMAIN_ID ----------------------------------------------------------------------


@pytest.mark.parametrize("value", [None, "", "0", "7", "101", "232"])
def test_usable_domain_ids_pass(clean_env, value):
    if value is not None:
        clean_env["ROS_DOMAIN_ID"] = value
    assert ros_env.domain_id_problem() is None


@pytest.mark.parametrize(
    "value, needle",
    [
        ("233", "pass 65535"),
        ("1000", "pass 65535"),
        ("-1", "-1 as domain 0"),  # rcl: strtoul -> SIZE_MAX, "use the default"
        ("010", "010 as 8"),
        ("0x10", "0x10 as 16"),
        ("abc", "allowed a decimal integer in [0, 232]"),
        (" 7", "allowed"),
        ("7 ", "allowed"),
    ],
)
def test_domain_ids_rcl_misreads_or_fastdds_cannot_use_are_refused(clean_env, value, needle):
    clean_env["ROS_DOMAIN_ID"] = value
    problem = ros_env.domain_id_problem()
    assert problem is not None and needle in problem
    assert problem.startswith(f"ROS_DOMAIN_ID = {value!r} is invalid")


def test_a_middleware_without_rtps_ports_takes_any_decimal_domain(clean_env):
    clean_env["RMW_IMPLEMENTATION"] = "rmw_zenoh_cpp"
    clean_env["ROS_DOMAIN_ID"] = "500"
    assert ros_env.domain_id_problem() is None
    clean_env["ROS_DOMAIN_ID"] = "-1"
    assert "allowed a decimal integer >= 0" in ros_env.domain_id_problem()


@pytest.mark.parametrize(
    "command",
    [
        ["imu_node"],
        ["run_scenario", "imu_noise", "--no-plots"],
        ["mcap_record", "--all", "-o", "{tmp}/x.mcap"],
        ["run_graph", "{launch}/imu.launch.yaml"],
    ],
    ids=lambda c: c[0],
)
@pytest.mark.parametrize("value", ["233", "-1"])
def test_executables_refuse_a_bad_domain_id_in_one_line(tmp_path, command, value):
    """Exit 2 and one line naming the variable, no traceback, nothing joins a graph (Fast
    DDS's own "port number is too high" error never printed) and no file is written."""
    launch = Path(__file__).resolve().parents[3] / "launch"
    argv = [a.format(tmp=tmp_path, launch=launch) for a in command]
    argv[0] = str(Path(sys.executable).parent / argv[0])
    env = {k: v for k, v in os.environ.items() if k not in SET_BY_DEFAULTS}
    env["ROS_DOMAIN_ID"] = value
    proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and f"ROS_DOMAIN_ID = {value!r} is invalid" in lines[0], lines
    assert "Traceback" not in proc.stderr and "port number" not in proc.stdout + proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_graph_refuses_a_bad_domain_id(clean_env):
    from mems_scenarios.base import Graph, ScenarioError

    clean_env["ROS_DOMAIN_ID"] = "240"
    with pytest.raises(ScenarioError, match="ROS_DOMAIN_ID = '240' is invalid"):
        Graph()
    with pytest.raises(ScenarioError, match="domain_id = 233 is invalid"):
        Graph(domain_id=233)


# -- sockets and packets ------------------------------------------------------------------


def receive_frames(graph, topic: str, proc, count: int = 3, timeout: float = 30.0) -> list:
    from mems_msgs.msg import AdcFrame
    from mems_sim.ros.qos import FRAME_QOS

    _ctx, ex, probe = graph
    frames = []
    probe.create_subscription(AdcFrame, topic, frames.append, FRAME_QOS)
    spin_until(ex, lambda: len(frames) >= count or proc.poll() is not None, timeout)
    return frames


def start_imu(env: dict, ns: str) -> subprocess.Popen:
    return subprocess.Popen(
        [
            str(Path(sys.executable).parent / "imu_node"),
            "--ros-args",
            "-p",
            "publish_imu:=false",
            "-p",
            "realtime_factor:=20",
            "-r",
            f"__ns:={ns}",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def stop(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        proc.terminate()
    try:
        return proc.communicate(timeout=30)[1]
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate()[1]


@pytest.mark.parametrize("range_value", ["LOCALHOST", ""])
def test_node_process_binds_only_loopback_sockets_and_talks_to_this_process(
    graph, domain_id, range_value
):
    """The node executable in LOCALHOST mode (or with an empty range) from a user's shell:
    every socket on 127.0.0.1; its frames reach this test process (another process with
    the profile)."""
    proc = start_imu(user_env(domain_id, ROS_AUTOMATIC_DISCOVERY_RANGE=range_value), "/lo")
    try:
        frames = receive_frames(graph, "/lo/adc", proc)
        sockets = inet_sockets(proc.pid)
    finally:
        err = stop(proc)
    assert len(frames) >= 3, err[-2000:]
    assert len([s for s in sockets if s[0] == "udp"]) >= 3, sockets
    assert [s for s in sockets if not is_loopback(s[1])] == [], sockets


def test_process_in_rmw_localhost_mode_talks_to_a_process_with_the_profile(graph, domain_id):
    """rmw_fastrtps' own LOCALHOST mode (ROS_STATIC_PEERS keeps the profile away) and the
    profile of this test process discover each other."""
    env = user_env(domain_id, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env["ROS_STATIC_PEERS"] = "127.0.0.1"
    proc = start_imu(env, "/rmw_lo")
    try:
        frames = receive_frames(graph, "/rmw_lo/adc", proc)
    finally:
        err = stop(proc)
    assert len(frames) >= 3, err[-2000:]


def network_address() -> str | None:
    """This machine's IPv4 address on its default route (no packet is sent), or None."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))
        except OSError:
            return None
        address = s.getsockname()[0]
    return None if ipaddress.ip_address(address).is_loopback else address


def test_no_rtps_packet_on_a_network_interface_with_an_empty_range(domain_id, tmp_path):
    """A scenario run with ROS_AUTOMATIC_DISCOVERY_RANGE="" sends no RTPS packet other than
    over loopback. tcpdump captures, on every interface, UDP packets of the domain's ports
    whose payload starts with 'RTPS' and whose addresses are not both loopback; one such
    packet sent by the test to this machine's network address checks the capture."""
    import shutil

    tcpdump = shutil.which("tcpdump") or shutil.which("tcpdump", path="/usr/sbin:/sbin")
    if tcpdump is None:
        pytest.skip("tcpdump is not installed (apt-get install tcpdump)")
    address = network_address()
    if address is None:
        pytest.skip("no IPv4 network interface: nothing could leave this machine")
    first_port = 7400 + 250 * domain_id
    last_port = first_port + 249
    bpf = (
        f"udp and portrange {first_port}-{last_port} and udp[8:4] = 0x52545053 "
        "and not (src net 127.0.0.0/8 and dst net 127.0.0.0/8)"
    )
    pcap = tmp_path / "capture.pcap"
    capture = subprocess.Popen(
        [tcpdump, "-i", "any", "-n", "-U", "-w", str(pcap), bpf],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        said = []
        for line in capture.stderr:  # "tcpdump: listening on any ..." once it captures
            said.append(line.strip())
            if "listening on" in line:
                break
        else:  # tcpdump ended: e.g. no permission to capture
            pytest.skip(f"tcpdump cannot capture here: {' '.join(said)}")
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b"RTPS\x02\x03" + bytes(14), (address, last_port))
        run = subprocess.run(
            [
                str(Path(sys.executable).parent / "run_scenario"),
                "sd_resonator",
                "--duration",
                "0.2",
                "--no-plots",
                "--no-progress",
                "--out",
                str(tmp_path / "run.mcap"),
                "--domain-id",
                str(domain_id),
            ],
            env=user_env(domain_id, ROS_AUTOMATIC_DISCOVERY_RANGE=""),
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert run.returncode == 0, run.stderr[-3000:]
        time.sleep(1.0)  # announcements sent as the participants closed
    finally:
        capture.terminate()
        capture.communicate(timeout=30)
    listing = subprocess.run(
        [tcpdump, "-r", str(pcap), "-n"], capture_output=True, text=True, check=True
    ).stdout.splitlines()
    probe = [line for line in listing if f"> {address}.{last_port}:" in line]
    assert len(probe) == 1, listing  # the capture sees a packet to the network address
    assert [line for line in listing if line not in probe] == []
