"""run_graph, through its command line: the launch YAML subset it reads, the one-line
refusals (exit 2), how it stops processes and reports failures, and a recorded
two-namespace graph stopped with SIGINT."""

import os
import shlex
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from conftest import spin_until

VENV_BIN = Path(sys.executable).parent
LIB = Path(sys.prefix) / "lib" / "mems_emulator"
RUN_GRAPH = str(VENV_BIN / "run_graph")


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def run_graph(args, env, timeout=60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [RUN_GRAPH, *map(str, args)], env=env, capture_output=True, text=True, timeout=timeout
    )


def refusal(args, env) -> str:
    """run_graph's exit status is 2 and stderr is one line; that line."""
    run = run_graph(args, env)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    assert lines[0].startswith("run_graph: error: ")
    return lines[0]


def commands(run: subprocess.CompletedProcess) -> list[list[str]]:
    assert run.returncode == 0, run.stderr
    return [shlex.split(line) for line in run.stdout.splitlines()]


# --------------------------------------------------------------------------- the subset


def test_args_let_include_param_remap_become_command_lines(tmp_path, subprocess_env):
    params = write(tmp_path / "p.yaml", "/**:\n  ros__parameters:\n    frame_size: 50\n")
    inner = write(
        tmp_path / "inner.launch.yaml",
        """\
        launch:
        - arg: {name: ns}
        - arg: {name: rate, default: "1.0"}
        - node:
            pkg: mems_emulator
            exec: imu_node
            name: imu_$(var ns)
            namespace: $(var ns)
            param:
            - {name: realtime_factor, value: $(var rate)}
            - from: $(var params)
            remap:
            - {from: truth, to: truth_$(var ns)}
        - let: {name: leaked, value: "yes"}
        """,
    )
    outer = write(
        tmp_path / "outer.launch.yaml",
        f"""\
        launch:
        - arg: {{name: first, default: a, description: first namespace}}
        - let: {{name: params, value: {params}}}
        - include:
            file: {inner}
            arg:
            - {{name: ns, value: $(var first)}}
        - include:
            file: {inner}
            arg:
            - {{name: ns, value: /b/}}
            - {{name: rate, value: "2"}}
        - node:
            pkg: mems_emulator
            exec: imu_noise_identifier_node
            output: screen
            param:
            - {{name: publish_period_s, value: 5.0}}
            - {{name: flag, value: true}}
            - {{name: list, value: [1, 2.5, x]}}
            - {{name: empty, value: ""}}
            - {{name: share, value: $(find-pkg-share mems_emulator)/x}}
        """,
    )
    from ament_index_python.packages import get_package_share_directory

    share = get_package_share_directory("mems_emulator")
    assert commands(run_graph([outer, "first:=x/y", "--dry-run"], subprocess_env)) == [
        [
            str(LIB / "imu_node"),
            *("--ros-args", "-r", "__node:=imu_x/y", "-r", "__ns:=/x/y"),
            *("-p", "realtime_factor:=1.0", "--params-file", str(params)),
            *("-r", "truth:=truth_x/y"),
        ],
        [
            str(LIB / "imu_node"),
            *("--ros-args", "-r", "__node:=imu_/b/", "-r", "__ns:=/b"),
            *("-p", "realtime_factor:=2", "--params-file", str(params)),
            *("-r", "truth:=truth_/b/"),
        ],
        [
            str(LIB / "imu_noise_identifier_node"),
            *("--ros-args", "-p", "publish_period_s:=5.0", "-p", "flag:=true"),
            *("-p", "list:=[1, 2.5, x]", "-p", "empty:=''", "-p", f"share:={share}/x"),
        ],
    ]
    # includes are not scoped: what the included file sets, and its arguments, stay set
    after = write(
        tmp_path / "after.launch.yaml",
        f"launch:\n- include: {{file: {inner}, arg: [{{name: ns, value: a}}, "
        f"{{name: params, value: {params}}}]}}\n"
        "- node: {pkg: mems_emulator, exec: imu_node, name: $(var leaked), "
        "namespace: $(var ns)}\n",
    )
    last = commands(run_graph([after, "--dry-run"], subprocess_env))[-1]
    assert last[-4:] == ["-r", "__node:=yes", "-r", "__ns:=/a"]


def test_show_args_lists_the_arguments_of_the_file_and_its_includes(tmp_path, subprocess_env):
    inner = write(tmp_path / "inner.launch.yaml", "launch:\n- arg: {name: rate, default: '2'}\n")
    f = write(
        tmp_path / "g.launch.yaml",
        f"""\
        launch:
        - arg: {{name: seed, default: "3", description: run seed}}
        - arg: {{name: where}}
        - include: {{file: {inner}}}
        - node: {{pkg: mems_emulator, exec: imu_node, namespace: $(var where)}}
        """,
    )
    run = run_graph([f, "--show-args"], subprocess_env)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines() == [
        "seed (default: '3'): run seed",
        "where (required)",
        "rate (default: '2')",
    ]


def test_dry_run_prints_the_recorder_then_the_nodes(tmp_path, subprocess_env):
    env = subprocess_env
    f = write(
        tmp_path / "g.launch.yaml",
        "launch:\n- node: {pkg: mems_emulator, exec: imu_node, namespace: a}\n",
    )
    out = tmp_path / "r.mcap"
    run = run_graph([f, "--dry-run", "--record", out, "--record-regex", "^/a/"], subprocess_env)
    recorder, imu = commands(run)
    # loss (and a stall) fails the run by default: the recorder's --fail-on-loss
    assert recorder[:7] == [
        str(LIB / "mcap_record"),
        "-o",
        str(out),
        "--fail-on-loss",
        "--regex",
        "^/a/",
        "--ros-args",
    ]
    assert recorder[7] == "-r" and recorder[8].startswith("__node:=mcap_record_")
    assert recorder[9:] == ["--log-level", "warn"]
    allowed = commands(
        run_graph([f, "--dry-run", "--record", out, "--allow-loss", "--stall-timeout", "2"], env)
    )[0]
    assert allowed[:6] == [str(LIB / "mcap_record"), "-o", str(out), "--stall-timeout", "2.0", "-a"]
    assert imu == [str(LIB / "imu_node"), "--ros-args", "-r", "__ns:=/a"]


def test_node_container_becomes_one_container_command_line(tmp_path, subprocess_env):
    f = write(
        tmp_path / "c.launch.yaml",
        """\
        launch:
        - arg: {name: ns, default: dev}
        - node_container:
            pkg: mems_emulator
            exec: component_container
            name: box
            namespace: $(var ns)
            composable_node:
            - pkg: mems_emulator
              plugin: imu_node
              name: imu
              namespace: $(var ns)
              param:
              - {name: frame_size, value: 50}
              remap:
              - {from: truth, to: truth_2}
            - pkg: mems_emulator
              plugin: mems_estimation.nodes.imu_noise_identifier_node:ImuNoiseIdentifierNode
        """,
    )
    assert commands(run_graph([f, "--dry-run"], subprocess_env)) == [
        [
            str(LIB / "component_container"),
            # the container's own name and namespace are not passed: they would rename
            # every node of the process
            *("--node", "imu_node", "--ros-args", "-r", "__node:=imu", "-r", "__ns:=/dev"),
            *("-p", "frame_size:=50", "-r", "truth:=truth_2"),
            *("--node", "mems_estimation.nodes.imu_noise_identifier_node:ImuNoiseIdentifierNode"),
            "--ros-args",
        ]
    ]


# --------------------------------------------------------------------------- refusals


NODE = "- node: {pkg: mems_emulator, exec: imu_node}\n"


@pytest.mark.parametrize(
    "text, cli, expected",
    [
        ("launch:\n- node: {pkg: mems_emulator\n", [], ":3:1: YAML syntax error"),
        ("launch:\n- node:\n\tpkg: x\n", [], "YAML syntax error"),
        ("launch:\n- node: {pkg: mems_emulator, exec: no_such_exe}\n", [], "'no_such_exe' not"),
        ("launch:\n- node: {pkg: no_such_pkg, exec: imu_node}\n", [], "package 'no_such_pkg'"),
        ("launch:\n- group: {}\n", [], "unsupported tag 'group'"),
        ("launch:\n- node: {pkg: mems_emulator, exec: imu_node, args: -x}\n", [], "'args'"),
        ("launch:\n- node: {pkg: mems_emulator}\n", [], "'exec' is required"),
        ("launch:\n- arg: {name: ns}\n" + NODE, [], "argument 'ns' is required"),
        ("launch:\n" + NODE, ["ns:=a"], "no argument 'ns' is declared"),
        ("launch:\n" + NODE, ["ns=a"], "name:=value"),
        (
            "launch:\n- node: {pkg: mems_emulator, exec: imu_node, name: $(env USER)}\n",
            [],
            "unsupported substitution $(env USER)",
        ),
        (
            "launch:\n- node: {pkg: mems_emulator, exec: imu_node, name: $(var nope)}\n",
            [],
            "$(var nope): no such",
        ),
        ("launch:\n- node: {pkg: mems_emulator, exec: $(var x}\n", [], "unterminated"),
        ("launch:\n- node: {pkg: mems_emulator, exec: imu_node, output: both}\n", [], "output"),
        ("launch:\n- include: {file: other.launch.py}\n", [], "only launch YAML"),
        ("launch:\n- include: {file: /nonexistent/x.launch.yaml}\n", [], "cannot read"),
        ("nodes: []\n", [], "one key 'launch'"),
        (
            "launch:\n- node:\n    pkg: mems_emulator\n    exec: imu_node\n"
            "    param: [{from: /nonexistent.yaml}]\n",
            [],
            "parameter file /nonexistent.yaml not found",
        ),
        (
            "launch:\n- node_container: {pkg: mems_emulator, exec: component_container, name: c}\n",
            [],
            "'composable_node' is required",
        ),
        (
            "launch:\n- node_container: {pkg: mems_emulator, exec: component_container, "
            "name: c, composable_node: []}\n",
            [],
            "'composable_node' must be a non-empty list",
        ),
        (
            "launch:\n- node_container: {pkg: mems_emulator, exec: component_container, "
            "name: c, composable_node: [{pkg: mems_emulator, plugin: imu_nod}]}\n",
            [],
            "composable_node 'imu_nod': executable 'imu_nod' not found",
        ),
        (
            "launch:\n- node_container: {pkg: mems_emulator, exec: component_container, "
            "name: c, composable_node: [{pkg: mems_emulator, plugin: 'nope_xyz:Cls'}]}\n",
            [],
            "module 'nope_xyz' of plugin 'nope_xyz:Cls' not found",
        ),
        (
            "launch:\n- node_container: {pkg: mems_emulator, exec: component_container, "
            "name: c, composable_node: [{pkg: mems_emulator, plugin: imu_node, "
            "extra_arg: [{name: use_intra_process_comms, value: 'true'}]}]}\n",
            [],
            "composable_node 1: unsupported attribute 'extra_arg'",
        ),
        (
            "launch:\n- node_container: {pkg: mems_emulator, exec: component_container, "
            "name: c, composable_node: [{pkg: mems_emulator}]}\n",
            [],
            "composable_node 1: attribute 'plugin' is required",
        ),
    ],
)
def test_refused_with_one_line_and_status_2(tmp_path, subprocess_env, text, cli, expected):
    f = write(tmp_path / "bad.launch.yaml", text)
    assert expected in refusal([f, *cli], subprocess_env)


def test_unknown_executable_line_names_file_node_package_and_folder(tmp_path, subprocess_env):
    f = write(tmp_path / "g.launch.yaml", "launch:\n- node: {pkg: mems_emulator, exec: nope}\n")
    assert refusal([f], subprocess_env) == (
        f"run_graph: error: {f}: node 'nope': executable 'nope' not found in package "
        f"'mems_emulator' ({LIB})"
    )


def test_include_cycle_and_bad_options_are_refused(tmp_path, subprocess_env):
    f = tmp_path / "loop.launch.yaml"
    write(f, f"launch:\n- include: {{file: {f}}}\n")
    assert "nested deeper" in refusal([f], subprocess_env)
    g = write(tmp_path / "g.launch.yaml", "launch:\n" + NODE)
    existing = tmp_path / "exists.mcap"
    existing.write_bytes(b"")
    assert "--overwrite" in refusal([g, "--record", existing], subprocess_env)
    assert "--duration" in refusal([g, "--duration", "0"], subprocess_env)
    assert "needs --record" in refusal([g, "--record-regex", "x"], subprocess_env)
    assert "need --record" in refusal([g, "--allow-loss"], subprocess_env)
    out = tmp_path / "new.mcap"
    assert "contradict" in refusal(
        [g, "--record", out, "--allow-loss", "--fail-on-loss"], subprocess_env
    )
    for bad in ("nan", "-1", "inf"):
        assert "--stall-timeout" in refusal(
            [g, "--record", out, "--stall-timeout", bad], subprocess_env
        )
    empty = write(tmp_path / "e.launch.yaml", "launch: []\n")
    assert "no node" in refusal([empty], subprocess_env)


def test_includes_that_fan_out_are_refused_in_bounded_time_and_memory(tmp_path, subprocess_env):
    """Each file includes the next one twice, 21 files deep (within the depth cap; 2**21 - 1
    loads, ~26 minutes before the cap): refused by the total-loads cap with one line and
    exit 2 within 30 s, with a peak resident size under 500 MB."""
    depth = 20
    write(tmp_path / f"f{depth}.launch.yaml", "launch:\n" + NODE)
    for k in range(depth - 1, -1, -1):
        inc = f"- include: {{file: {tmp_path / f'f{k + 1}.launch.yaml'}}}\n"
        write(tmp_path / f"f{k}.launch.yaml", "launch:\n" + inc + inc)
    measure = (
        "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:], "
        "capture_output=True, text=True); print(r.returncode); print(r.stderr, end=''); "
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)"
    )
    t0 = time.monotonic()
    run = subprocess.run(
        [sys.executable, "-c", measure, RUN_GRAPH, str(tmp_path / "f0.launch.yaml")],
        env=subprocess_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    elapsed = time.monotonic() - t0
    status, *stderr, peak_kib = run.stdout.splitlines()
    assert status == "2" and len(stderr) == 1, run.stdout
    assert stderr[0].startswith("run_graph: error: ") and "more than 1000 launch files" in stderr[0]
    assert elapsed < 30, elapsed
    assert int(peak_kib) < 500 * 1024, peak_kib


def test_a_nul_character_in_a_value_is_refused_before_anything_starts(tmp_path, subprocess_env):
    f = write(
        tmp_path / "nul.launch.yaml",
        "launch:\n- node: {pkg: mems_emulator, exec: imu_node, name: imu}\n"
        '- node: {pkg: mems_emulator, exec: imu_node, name: "b\\0d"}\n',
    )
    assert "a NUL character in 'b\\x00d'" in refusal([f], subprocess_env)


# --------------------------------------------------------------------------- the runner


@pytest.fixture
def fake_pkg(tmp_path, subprocess_env):
    """(make, env): ``make(name, body)`` puts a shell script standing in for a node
    executable (it ignores --ros-args) in package ``fake`` of an ament prefix of its own;
    ``env`` finds that package."""
    prefix = tmp_path / "prefix"
    (prefix / "share/ament_index/resource_index/packages").mkdir(parents=True)
    (prefix / "share/ament_index/resource_index/packages/fake").write_text("")
    (prefix / "lib/fake").mkdir(parents=True)

    def make(name: str, body: str, shebang: str = "#!/bin/bash") -> None:
        path = prefix / "lib/fake" / name
        path.write_text(f"{shebang}\n{body}\n")
        path.chmod(0o755)

    env = dict(subprocess_env)
    env["AMENT_PREFIX_PATH"] = f"{prefix}{os.pathsep}{env.get('AMENT_PREFIX_PATH', sys.prefix)}"
    return make, env


def graph_file(tmp_path: Path, *nodes: str, output: str = "screen") -> Path:
    text = "launch:\n" + "".join(
        f"- node: {{pkg: fake, exec: {n}, name: {n}, output: {output}}}\n" for n in nodes
    )
    return write(tmp_path / "fake.launch.yaml", text)


def test_a_failing_node_stops_the_graph_and_is_named(tmp_path, fake_pkg):
    make, env = fake_pkg
    make("slow", "trap 'exit 0' INT; while true; do sleep 0.05; done")
    make("bad", "echo starting; echo broken >&2; sleep 0.3; exit 3")
    logs = tmp_path / "logs"
    t0 = time.monotonic()
    run = run_graph([graph_file(tmp_path, "slow", "bad", output="log"), "--log-dir", logs], env)
    assert time.monotonic() - t0 < 5
    assert run.returncode == 1
    problems = [line for line in run.stderr.splitlines() if line.startswith("run_graph: error")]
    assert problems == [
        f"run_graph: error: /bad (bad) exited with status 3 (log: {logs / 'bad.log'})"
    ]
    assert "[bad] broken" in run.stderr  # a log node's stderr is on the screen too
    assert "starting" not in run.stdout
    # stdout and stderr are separate pipes pumped by separate threads (as in ros2 launch):
    # both lines are in the log, their relative order is not defined.
    assert sorted((logs / "bad.log").read_text().splitlines()) == ["broken", "starting"]


def test_a_node_that_ignores_the_stop_signal_is_killed(tmp_path, fake_pkg):
    make, env = fake_pkg
    make("stubborn", "trap '' INT TERM; while true; do sleep 0.05; done")
    make("polite", "trap 'exit 0' INT; while true; do sleep 0.05; done")
    f = graph_file(tmp_path, "stubborn", "polite")
    t0 = time.monotonic()
    run = run_graph([f, "--duration", "0.5", "--kill-timeout", "0.5"], env)
    assert 0.9 < time.monotonic() - t0 < 5
    assert run.returncode == 1
    assert run.stderr.strip().splitlines() == [
        "run_graph: error: /stubborn (stubborn) did not stop after SIGINT; killed"
    ]


def test_no_node_outlives_a_killed_run_graph(tmp_path, fake_pkg):
    """run_graph SIGKILLed (no handler of its own runs): every node, each in a session of
    its own, gets SIGTERM from the parent-death signal and is gone within 5 s."""
    make, env = fake_pkg
    marker = tmp_path / "terminated"
    make("worker", f"trap 'touch {marker}-$$; exit 0' TERM; while true; do sleep 0.05; done")
    f = write(
        tmp_path / "two.launch.yaml",
        "launch:\n" + "".join(f"- node: {{pkg: fake, exec: worker, name: w{k}}}\n" for k in (1, 2)),
    )
    proc = subprocess.Popen(
        [str(VENV_BIN / "run_graph"), str(f)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and len(processes_naming(str(tmp_path / "prefix"))) < 2:
            time.sleep(0.05)
        assert len(processes_naming(str(tmp_path / "prefix"))) == 2
        proc.kill()
        proc.wait()
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and processes_naming(str(tmp_path / "prefix")):
            time.sleep(0.05)
        assert not processes_naming(str(tmp_path / "prefix"))
        assert len(list(tmp_path.glob("terminated-*"))) == 2  # both got SIGTERM
    finally:
        for line in processes_naming(str(tmp_path / "prefix")):
            print("left running:", line)


def watched_graph(cmd: list[str], env) -> subprocess.Popen:
    """run_graph in a session of its own, its output piped as text."""
    return subprocess.Popen(
        cmd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def end_watch(proc: subprocess.Popen, executor, watcher) -> None:
    """The test's watcher node shut down; run_graph's session killed if it still runs."""
    executor.shutdown()
    watcher.destroy_node()
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def test_a_stalled_recorder_is_loss_in_the_exit_status(tmp_path, subprocess_env, ros_context):
    """The recorder SIGSTOPped while an IMU publishes 1000 frames/s: the recorder stays
    stopped until a watcher of the test has seen 4 frame histories more go by (an IMU slowed
    by a loaded machine takes longer; 6 s at full speed), so the writer's and the reader's
    histories overflow, and run_graph exits 1 naming the lost topic (it exited 0 before)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from mems_msgs.msg import AdcFrame
    from mems_sim.ros.qos import FRAME_DEPTH, FRAME_QOS

    namespace = f"/stalled_{os.getpid()}"
    watcher = rclpy.create_node("stall_watcher", context=ros_context)
    seen = []
    watcher.create_subscription(
        AdcFrame, f"{namespace}/adc", lambda m: seen.append(m.first_sample_index), FRAME_QOS
    )
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(watcher)
    graph = write(
        tmp_path / "imu.launch.yaml",
        "launch:\n- node: {pkg: mems_emulator, exec: imu_node, name: imu, namespace: "
        + namespace
        + ", param: [{name: sample_rate_hz, value: 1000.0}, {name: frame_size, value: 1}]}\n",
    )
    bag = tmp_path / "stalled.mcap"
    proc = watched_graph(
        [RUN_GRAPH, str(graph), "--record", str(bag), "--fail-on-loss", "--kill-timeout", "30"],
        subprocess_env,
    )
    try:
        deadline = time.monotonic() + 60
        recorder = []
        while time.monotonic() < deadline and not (recorder and bag.exists()):
            recorder = [
                int(line.split()[0])
                for line in processes_naming_with_pid(str(bag))
                if "mcap_record" in line
            ]
            time.sleep(0.1)
        assert recorder and bag.exists()
        while time.monotonic() < deadline and bag.stat().st_size < 100_000:
            time.sleep(0.1)  # frames recorded: the first chunks are in the file
        assert spin_until(executor, lambda: seen, timeout=30), "the watcher saw no frame"
        os.kill(recorder[0], signal.SIGSTOP)
        stopped_at = seen[-1]
        overflowed = spin_until(
            executor, lambda: seen[-1] - stopped_at >= 4 * FRAME_DEPTH, timeout=60
        )
        os.kill(recorder[0], signal.SIGCONT)
        assert overflowed, f"the IMU published {seen[-1] - stopped_at} frames in 60 s"
        time.sleep(1.0)
        os.kill(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=90)
    finally:
        end_watch(proc, executor, watcher)
    assert proc.returncode == 1, stdout[-2000:] + stderr[-2000:]
    assert "recorder mcap_record: the recording lost data" in stderr, stderr[-2000:]
    assert f"lost data: {namespace}/" in stderr, stderr[-2000:]
    assert "stalled:" not in stdout + stderr  # the recorder stopped, not the IMU


#: The stalled-node runs: which node is SIGSTOPped, its topic that stalls, for how long [s],
#: and run_graph's --stall-timeout (None: the recorder's default, 5 s).
STALLS = [
    pytest.param("imu_node", "adc", 4.0, 1.5, id="emulator"),
    pytest.param("imu_corrector_node", "data_corrected", 4.0, 1.5, id="estimator"),
    pytest.param("imu_node", "adc", 10.0, None, id="emulator-10s", marks=pytest.mark.slow),
    pytest.param(
        "imu_corrector_node",
        "data_corrected",
        10.0,
        None,
        id="estimator-10s",
        marks=pytest.mark.slow,
    ),
]


@pytest.mark.parametrize("exe, topic, stop_s, timeout", STALLS)
def test_a_stalled_node_is_a_stall_in_the_exit_status(
    exe, topic, stop_s, timeout, tmp_path, subprocess_env, ros_context
):
    """An emulator (imu_node) or the estimator downstream of it (imu_corrector_node)
    SIGSTOPped while the graph records, then continued: its topic had been sending steadily
    and sent nothing for ``stop_s`` s with its publisher still in the graph, so run_graph
    exits 1 naming the stalled topic (it exited 0 before: nothing was lost in transport).
    A watcher of the test waits for the recorder's subscription and steady data before the
    stop, and for the data to flow again after it (robust to a loaded machine)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    from mems_estimation.identification.imu_calibration import neutral_calibration
    from mems_estimation.identification.imu_calibration_io import save_yaml
    from mems_msgs.msg import AdcFrame

    namespace = f"/stall_{os.getpid()}"
    calibration = tmp_path / "neutral.yaml"
    save_yaml(neutral_calibration(), calibration)
    graph = write(
        tmp_path / "imu.launch.yaml",
        f"""\
        launch:
        - node: {{pkg: mems_emulator, exec: imu_node, name: imu, namespace: {namespace},
                  param: [{{name: frame_size, value: 10}}]}}
        - node: {{pkg: mems_emulator, exec: imu_corrector_node, name: corrector,
                  namespace: {namespace}, param: [{{name: calibration_yaml, value: {calibration}}}]}}
        """,
    )
    watched = f"{namespace}/{topic}"
    watcher = rclpy.create_node("stall_watcher", context=ros_context)
    seen = []
    watcher.create_subscription(
        AdcFrame if topic == "adc" else Imu,
        watched,
        lambda m: seen.append(1),
        QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT),
    )
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(watcher)
    bag = tmp_path / "stalled.mcap"
    cmd = [RUN_GRAPH, str(graph), "--record", str(bag), "--log-dir", str(tmp_path / "logs")]
    cmd += ["--kill-timeout", "30"] + ([] if timeout is None else ["--stall-timeout", str(timeout)])
    proc = watched_graph(cmd, subprocess_env)
    try:
        # the recorder (and, on adc, the corrector) subscribe next to the watcher
        subscribers = 3 if topic == "adc" else 2
        assert spin_until(
            executor, lambda: watcher.count_subscribers(watched) >= subscribers, timeout=60
        ), "the recorder did not subscribe"
        # 30 frames (data_corrected: a message per sample, 10 per frame): past the start-up
        steady = 30 if topic == "adc" else 300
        assert spin_until(executor, lambda: len(seen) >= steady, timeout=60), "no steady data"
        node = [
            int(line.split()[0])
            for line in processes_naming_with_pid(f"__ns:={namespace}")
            if f"/{exe} " in line
        ]
        assert len(node) == 1, node
        os.kill(node[0], signal.SIGSTOP)
        try:
            spin_until(executor, lambda: False, timeout=stop_s)
            before = len(seen)
        finally:
            os.kill(node[0], signal.SIGCONT)
        assert spin_until(executor, lambda: len(seen) >= before + steady, timeout=60), "no data"
        os.kill(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=90)
    finally:
        end_watch(proc, executor, watcher)
    assert proc.returncode == 1, stdout[-2000:] + stderr[-2000:]
    assert "recorder mcap_record: the recording lost data or stalled" in stderr, stderr[-2000:]
    line = next(x for x in stderr.splitlines() if x.startswith("[mcap_record] mcap_record: error"))
    assert f"stalled: {watched} (" in line, stderr[-2000:]
    silence = float(line.split(f"stalled: {watched} (")[1].split(" s without data)")[0])
    assert silence >= stop_s - 0.5, line


def test_a_node_that_cannot_start_is_named_and_nothing_else_runs(tmp_path, fake_pkg):
    make, env = fake_pkg
    make("broken", "true", shebang="#!/nonexistent/interpreter")
    make("later", "touch " + str(tmp_path / "ran"))
    run = run_graph([graph_file(tmp_path, "broken", "later")], env)
    assert run.returncode == 1
    assert run.stderr.startswith("run_graph: error: /broken (broken) failed to start: ")
    assert len(run.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "ran").exists()


def test_nodes_that_finish_on_their_own_end_the_run_with_status_0(tmp_path, fake_pkg):
    make, env = fake_pkg
    make("quick", "echo done")
    make("quicker", "echo 'to stderr' >&2")
    run = run_graph([graph_file(tmp_path, "quick", "quicker")], env)
    assert run.returncode == 0, run.stderr
    assert run.stdout == "[quick] done\n"
    assert run.stderr == "[quicker] to stderr\n"


# --------------------------------------------------------------------------- a real graph


GRAPH = """\
launch:
- arg: {name: first, default: left, description: namespace of the first IMU}
- arg: {name: second, default: right}
- arg: {name: rate, default: "20.0"}
- node:
    pkg: mems_emulator
    exec: imu_node
    name: imu
    namespace: $(var first)
    param:
    - {name: realtime_factor, value: $(var rate)}
    - {name: frame_size, value: 100}
    - {name: seed, value: 1}
    # no sensor_msgs/Imu per sample: 2 x 2000 messages/s would starve the recorder of a
    # loaded machine into a real loss, which is not this graph's subject (the stop is)
    - {name: publish_imu, value: false}
    - {name: start_when_matched, value: true}
    - {name: wait_for_subscribers, value: "adc:2"}
- include:
    file: INNER
    arg:
    - {name: ns, value: $(var second)}
    - {name: rate, value: $(var rate)}
"""
INNER = """\
launch:
- arg: {name: ns}
- arg: {name: rate}
- let: {name: truth_topic, value: truth_remapped}
- node:
    pkg: mems_emulator
    exec: imu_node
    name: imu
    namespace: $(var ns)
    output: screen
    param:
    - {name: realtime_factor, value: $(var rate)}
    - {name: seed, value: 2}
    - {name: publish_imu, value: false}
    - {name: start_when_matched, value: true}
    - {name: wait_for_subscribers, value: "adc:2"}
    - from: PARAMS
    remap:
    - {from: truth, to: $(var truth_topic)}
"""


def processes_naming(text: str) -> list[str]:
    """Command lines of the running processes that contain ``text`` (``pgrep -f``)."""
    return [line.split(" ", 1)[1] for line in processes_naming_with_pid(text)]


def processes_naming_with_pid(text: str) -> list[str]:
    """``PID COMMAND LINE`` of the running processes whose command line contains ``text``.

    A child with its parent's very command line is left out: it is a fork that has not
    yet exec'd (a shell's subshell on its way to ``sleep`` carries the shell's command
    line for a moment), not another process of its own. A child that exec'd a program
    of its own (``mcap_record`` under ``run_graph``) is listed, and so is a fork whose
    parent is gone, so nothing left running is hidden.
    """
    lines, parents = {}, {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            line = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        if text in line:
            lines[entry.name] = line
            parents[entry.name] = stat.rsplit(")", 1)[1].split()[1]
    return [f"{pid} {line}" for pid, line in lines.items() if lines.get(parents[pid]) != line]


def stderr_of(f) -> str:
    f.seek(0)
    return f.read()[-3000:]


@pytest.mark.parametrize("stop", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_graph_with_args_two_namespaces_and_recorder_stops_cleanly_on_a_signal(
    stop, tmp_path, graph, subprocess_env
):
    """SIGINT (Ctrl-C), SIGTERM (``kill``) or SIGHUP (the terminal closed): every node and
    the recorder stop and finalise (a Summary the mcap library and rosbags read), and no
    process of the graph outlives run_graph."""
    from mems_msgs.msg import AdcFrame
    from mems_sim.bag.player import read_messages
    from mems_sim.ros.qos import FRAME_QOS

    _, ex, probe = graph
    params = write(tmp_path / "p.yaml", "/**:\n  ros__parameters:\n    frame_size: 50\n")
    inner = write(tmp_path / "inner.launch.yaml", INNER.replace("PARAMS", str(params)))
    outer = write(tmp_path / "g.launch.yaml", GRAPH.replace("INNER", str(inner)))
    bag = tmp_path / "graph.mcap"
    got = {"/a/adc": [], "/b/adc": []}
    for topic, box in got.items():
        probe.create_subscription(AdcFrame, topic, box.append, FRAME_QOS)
    out, err = (open(tmp_path / n, "w+") for n in ("stdout", "stderr"))
    proc = subprocess.Popen(
        [str(VENV_BIN / "run_graph"), str(outer), "first:=a", "second:=/b"]
        + ["--record", str(bag), "--log-dir", str(tmp_path / "logs"), "--duration", "60"]
        # the stop deadline has its own test (a slow stop on a loaded machine is not this
        # test's failure)
        + ["--kill-timeout", "30"],
        env=subprocess_env,
        stdout=out,
        stderr=err,
        start_new_session=True,
    )
    recorded = ("/a/adc", "/a/truth", "/b/adc", "/b/truth_remapped")
    try:
        # the recorder (a second subscriber next to the probe) has subscribed every topic
        assert spin_until(
            ex,
            lambda: all(probe.count_subscribers(t) >= 1 + t.endswith("adc") for t in recorded),
            timeout=40,
        ), stderr_of(err)
        # then 10 more frames each (20 frames/s per IMU)
        n = {t: len(v) for t, v in got.items()}
        assert spin_until(ex, lambda: all(len(v) >= n[t] + 10 for t, v in got.items()), 20)
        os.kill(proc.pid, getattr(signal, stop))
        assert proc.wait(timeout=90) == 0, stderr_of(out) + stderr_of(err)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    # the graph's processes (each started in a session of its own) are gone too
    assert not processes_naming(str(tmp_path))
    out.seek(0)
    err.seek(0)
    stdout, stderr = out.read(), err.read()
    assert "run_graph: error" not in stderr, stderr
    assert f"[mcap_record] {bag}:" in stdout  # the recorder's summary, stopped last
    # the first IMU logs to a file, the second one to the screen
    assert (tmp_path / "logs" / "a.imu.log").is_file()
    assert not (tmp_path / "logs" / "b.imu.log").exists()
    sizes: dict[str, set] = {}
    for topic, _type, _t, msg in read_messages(str(bag)):
        if hasattr(msg, "num_samples"):
            sizes.setdefault(topic, set()).add(msg.num_samples)
    # -p frame_size for /a, the parameter file for /b; /b's truth remapped
    assert sizes["/a/adc"] == {100} and sizes["/a/truth"] == {100}
    assert sizes["/b/adc"] == {50} and sizes["/b/truth_remapped"] == {50}
    assert "/b/truth" not in sizes
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    with open(bag, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None and summary.statistics.message_count > 0
    with AnyReader([bag]) as reader:
        assert {"/a/adc", "/b/adc"} <= {c.topic for c in reader.connections}
