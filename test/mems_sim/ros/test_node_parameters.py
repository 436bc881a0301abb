"""Parameters of a node executable through the standard parameter services, from another
process: numeric ranges in DescribeParameters, out-of-range values refused with a reason
naming the range, a whole number accepted (and stored as a double) for a float parameter,
parameters read at start refused at runtime, a clean exit on SIGINT; and the exit code 2
with one line for an invalid value at start."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor

from mems_msgs.msg import AdcFrame
from mems_sim.ros.qos import FRAME_QOS

NS = "/ptest"
NODE = f"{NS}/imu"  # ImuNode's name in the namespace given on the command line


def _call(ex, client, request, timeout=20.0):
    assert client.wait_for_service(timeout_sec=timeout), client.srv_name
    future = client.call_async(request)
    ex.spin_until_future_complete(future, timeout_sec=timeout)
    assert future.done(), client.srv_name
    return future.result()


def _value(**kw) -> ParameterValue:
    if "integer" in kw:
        return ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=kw["integer"])
    return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=kw["double"])


@pytest.fixture
def imu_process(subprocess_env):
    """The imu_node executable in /ptest, realtime_factor given as a whole number."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mems_sim.nodes.imu_node",
            "--ros-args",
            "-p",
            "realtime_factor:=200",
            "-p",
            "publish_imu:=false",
            "-p",
            "frame_size:=100",
            "-r",
            f"__ns:={NS}",
        ],
        env=subprocess_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    yield proc
    if proc.poll() is None:
        proc.kill()
        proc.communicate(timeout=30)


def test_parameters_through_services_from_another_process(imu_process, ros_context):
    import rclpy

    node = rclpy.create_node("param_probe", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    frames = []
    node.create_subscription(AdcFrame, f"{NS}/adc", frames.append, FRAME_QOS)
    describe = node.create_client(DescribeParameters, f"{NODE}/describe_parameters")
    get = node.create_client(GetParameters, f"{NODE}/get_parameters")
    set_ = node.create_client(SetParameters, f"{NODE}/set_parameters")
    try:
        # ranges as rcl_interfaces ranges (step 0), "set at start" where it is
        res = _call(
            ex,
            describe,
            DescribeParameters.Request(names=["realtime_factor", "frame_size", "sample_rate_hz"]),
        )
        rtf, frame_size, fs = res.descriptors
        assert rtf.type == ParameterType.PARAMETER_DOUBLE and not rtf.read_only
        (r,) = rtf.floating_point_range
        assert (r.from_value, r.to_value, r.step) == (0.0, 1.0e6, 0.0)
        assert not rtf.integer_range and "set at start" not in rtf.additional_constraints
        (i,) = frame_size.integer_range
        assert (i.from_value, i.to_value, i.step) == (1, 1_000_000, 0)
        assert frame_size.type == ParameterType.PARAMETER_INTEGER
        assert "set at start" in frame_size.additional_constraints
        assert not frame_size.read_only and fs.floating_point_range

        # the whole number given at start is stored as a double
        res = _call(ex, get, GetParameters.Request(names=["realtime_factor"]))
        (v,) = res.values
        assert v.type == ParameterType.PARAMETER_DOUBLE and v.double_value == 200.0

        def set_one(name, value):
            req = SetParameters.Request(parameters=[Parameter(name=name, value=value)])
            (result,) = _call(ex, set_, req).results
            return result

        # out of range: a float and a whole number, both refused naming parameter, value and
        # range (by rclpy's check of floating_point_range: "Min: 0.0, Max: 1000000.0")
        for value in (_value(double=2.0e6), _value(integer=2_000_000)):
            result = set_one("realtime_factor", value)
            assert not result.successful
            assert "realtime_factor" in result.reason and "2000000" in result.reason
            assert "1000000" in result.reason.replace(".0", "")  # the upper bound
        # the exclusive lower bound (rclpy's range is inclusive; the spec refuses it)
        result = set_one("realtime_factor", _value(integer=0))
        assert not result.successful and "(0.0, 1000000.0]" in result.reason
        # a parameter the device reads at start: refused with a reason saying so
        result = set_one("frame_size", _value(integer=20))
        assert not result.successful and "read at start" in result.reason
        result = set_one("frame_size", _value(integer=0))  # out of range: said first
        assert not result.successful and "frame_size" in result.reason
        assert "1000000" in result.reason and "read at start" not in result.reason

        # an in-range whole number: accepted and stored as a double; the pacing goes on
        assert set_one("realtime_factor", _value(integer=300)).successful
        res = _call(ex, get, GetParameters.Request(names=["realtime_factor", "frame_size"]))
        rtf_v, fsz_v = res.values
        assert rtf_v.type == ParameterType.PARAMETER_DOUBLE and rtf_v.double_value == 300.0
        assert fsz_v.integer_value == 100
        n0 = len(frames)
        deadline = time.monotonic() + 30
        while len(frames) < n0 + 20 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        indices = [m.first_sample_index for m in frames]
        assert len(indices) >= n0 + 20
        assert all(b - a == 100 for a, b in zip(indices, indices[1:]))
    finally:
        ex.shutdown()
        node.destroy_node()
    assert imu_process.poll() is None, imu_process.communicate()
    imu_process.send_signal(signal.SIGINT)
    _, err = imu_process.communicate(timeout=30)
    assert imu_process.returncode == 0, err[-2000:]


def test_realtime_factor_change_paces_on_from_the_current_index(ros_context):
    """In process: a new realtime_factor continues the pacing at the current sample index."""
    from conftest import params
    from rclpy.parameter import Parameter as RclpyParameter

    from mems_sim.nodes.imu_node import ImuNode

    emu = ImuNode(
        context=ros_context,
        autostart=False,
        parameter_overrides=params(publish_imu=False, frame_size=100, realtime_factor=10),
    )
    try:
        assert emu.p["realtime_factor"] == 10.0
        assert isinstance(emu.get_parameter("realtime_factor").value, float)
        emu.start()
        period = emu._timer.timer_period_ns  # 100 / 100 Hz / 10 = 0.1 s, at most 0.05 s
        emu._on_timer()  # the first tick starts the wall clock of the pacing
        emu.next_index = 500  # as if 500 samples were published
        t_set = time.monotonic()
        (result,) = emu.set_parameters([RclpyParameter("realtime_factor", value=40)])
        assert result.successful
        assert emu.p["realtime_factor"] == 40.0
        assert emu.get_parameter("realtime_factor").type_ == RclpyParameter.Type.DOUBLE
        assert emu._index_start == 500 and emu._timer.timer_period_ns == 25_000_000 < period
        # due from now on: 500 + (wall time since the change) * 40 * 100 Hz
        assert t_set <= emu._wall_start <= time.monotonic()
        (result,) = emu.set_parameters([RclpyParameter("realtime_factor", value=-1.0)])
        assert not result.successful and "realtime_factor" in result.reason
        (result,) = emu.set_parameters([RclpyParameter("seed", value=3)])
        assert not result.successful and "read at start" in result.reason
        assert emu.p["seed"] == 0
    finally:
        emu.destroy_node()


@pytest.mark.parametrize(
    "arg, needle",
    [
        # a whole number for a float parameter, at its excluded bound
        ("realtime_factor:=0", "'realtime_factor' = 0.0 is out of range: allowed (0.0, 1000000.0]"),
        ("realtime_factor:=-2.5", "'realtime_factor' = -2.5 is out of range: allowed (0.0, 1"),
        ("frame_size:=0", "'frame_size' = 0 is out of range: allowed [1, 1000000] samples"),
    ],
)
def test_out_of_range_at_start_exits_2_with_one_line(arg, needle, subprocess_env):
    run = subprocess.run(
        [sys.executable, "-m", "mems_sim.nodes.imu_node", "--ros-args", "-p", arg],
        env=subprocess_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], run.stderr


@pytest.mark.parametrize(
    "rules, needle",
    [
        (["-p", "durations_s:=3"], "did you mean duration_s"),
        (["-p", "noequals"], "a rule is NAME:=VALUE"),
        (["-r", "x"], "a rule is NAME:=VALUE"),
    ],
)
def test_a_node_refuses_unknown_or_malformed_rules(rules, needle, subprocess_env):
    """An unknown -p name is refused with the close matches, a malformed rule too (rcl's
    RCLError was a traceback): one line, exit 2, before the node starts."""
    run = subprocess.run(
        [str(Path(sys.executable).parent / "imu_node"), "--ros-args", *rules],
        capture_output=True,
        text=True,
        env=subprocess_env,
        timeout=60,
    )
    assert run.returncode == 2, run.stderr[-1000:]
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], run.stderr[-1000:]


def test_a_wildcard_parameter_file_with_other_nodes_names_only_warns(tmp_path, subprocess_env):
    """A ``/**`` file serves several nodes: a name this node lacks is a warning, not an error."""
    params = tmp_path / "all.yaml"
    params.write_text("/**:\n  ros__parameters:\n    duration_s: 0.3\n    channels: a,b\n")
    proc = subprocess.Popen(
        [str(Path(sys.executable).parent / "imu_node"), "--ros-args", "--params-file", str(params)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=subprocess_env,
    )
    try:
        line = proc.stderr.readline()  # the warning comes before the node spins
        assert "parameters given but not declared: channels" in line, line
        assert proc.poll() is None  # and the node runs
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
