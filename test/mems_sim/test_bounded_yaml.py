"""The bounded YAML reader and every consumer of a user's YAML file: alias bombs, deep
nesting, non-UTF-8 bytes, FIFOs and /dev/zero are refused with the consumer's one-line
error, in bounded time and memory; a bounded fuzz of the consumers (fixed seeds)."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from mems_sim import bounded_yaml

#: A 900-byte parameter file whose aliases expand to 9^9 strings when walked.
ALIAS_BOMB = (
    "/**:\n  ros__parameters:\n"
    + "    a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n"
    + "".join(
        f"    {c}: &{c} [{', '.join(['*' + p] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi")
    )
)
DEEP = "a: " + "[" * 20_000 + "]" * 20_000 + "\n"


def test_limits_are_refused_with_one_line(tmp_path):
    cases = {
        "alias": ALIAS_BOMB,
        "deep": DEEP,
    }
    for name, text in cases.items():
        with pytest.raises(yaml.YAMLError) as refused:
            bounded_yaml.load(text)
        assert isinstance(refused.value, bounded_yaml.YamlLimitError), name
        assert "\n" not in str(refused.value), name
    bad = tmp_path / "latin1.yaml"
    bad.write_bytes(b"name: caf\xe9\n")
    with pytest.raises(bounded_yaml.YamlLimitError, match="not UTF-8"):
        bounded_yaml.load_file(bad)
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    link = tmp_path / "zero.yaml"
    link.symlink_to("/dev/zero")
    for path in (fifo, link, tmp_path):
        t0 = time.monotonic()
        with pytest.raises((bounded_yaml.YamlLimitError, OSError)):
            bounded_yaml.load_file(path)
        assert time.monotonic() - t0 < 1.0
    big = tmp_path / "big.yaml"
    big.write_text("a: 1\n" * 100)
    with pytest.raises(bounded_yaml.YamlLimitError, match="larger than"):
        bounded_yaml.load_file(big, max_bytes=100)
    assert bounded_yaml.load("a: [1, {b: 2.5}]\n") == {"a": [1, {"b": 2.5}]}


def _consumers():
    """(name, load(path), the error classes its callers report in one line)."""
    from mems_estimation.filters.stage_ekf import load_model
    from mems_estimation.identification.imu_calibration import CalibrationError
    from mems_estimation.identification.imu_calibration_io import load_yaml as load_calibration
    from mems_scenarios.launch_file import GraphError, load_graph
    from mems_sim.devices.imu_profiles import ProfileError, load_profile
    from mems_sim.ros.params_file import ParamsFileError, load_params_file
    from mems_sim.ros.qos_yaml import load_overrides as load_qos_overrides

    return [
        ("params_file", load_params_file, (ParamsFileError,)),
        ("launch", lambda p: load_graph(Path(p), {}), (GraphError,)),
        ("qos_overrides", load_qos_overrides, (ValueError,)),
        ("imu_profile", load_profile, (ProfileError,)),
        ("stage_model", load_model, (ValueError,)),
        ("imu_calibration", load_calibration, (CalibrationError,)),
    ]


def _fuzz_texts(seed: int, n: int) -> list[bytes]:
    """Hostile and malformed YAML: bombs, nesting, mutations of a parameter file."""
    rng = random.Random(seed)
    base = (
        b"/imu/imu:\n  ros__parameters:\n    seed: 3\n    rate_hz: 200.0\n"
        b"    names: [a, b]\n    nested:\n      x: 1\n"
    )
    texts = [ALIAS_BOMB.encode(), DEEP.encode(), b"\xff\xfe\x00", b"", b"---\n...\n", b"[" * 5000]
    alphabet = b"&*[]{}:,-!?|>'\"#%@`\n \t\\\x00\xc3\xa9"
    while len(texts) < n:
        data = bytearray(base)
        for _ in range(rng.randint(1, 12)):
            pos = rng.randrange(len(data) + 1)
            op = rng.random()
            if op < 0.4:
                data[pos:pos] = bytes(rng.choice(alphabet) for _ in range(rng.randint(1, 6)))
            elif op < 0.7 and data:
                del data[pos : pos + rng.randint(1, 8)]
            else:
                data[pos:pos] = data[: rng.randint(0, 40)]
        texts.append(bytes(data))
    return texts


def test_fuzzed_yaml_gets_one_line_errors_in_bounded_time(tmp_path):
    """A few hundred generated inputs per consumer: each is loaded or refused with the
    consumer's error (never a traceback class of its own), each in well under a second."""
    consumers = _consumers()
    warm = tmp_path / "warm.yaml"
    warm.write_text("a: 1\n")
    for _, load, errors in consumers:  # imports on the first call are not the input's cost
        try:
            load(str(warm))
        except errors:
            pass
    worst = 0.0
    for k, text in enumerate(_fuzz_texts(seed=2026, n=250)):
        path = tmp_path / f"case{k}.yaml"
        path.write_bytes(text)
        for name, load, errors in consumers:
            # CPU time of this process: the bound is the reader's work, not the host's load
            t0 = time.process_time()
            try:
                load(str(path))
            except errors as exc:
                assert "\n" not in str(exc).strip(), (name, k, str(exc))
            worst = max(worst, time.process_time() - t0)
    assert worst < 2.0, worst


@pytest.mark.parametrize("where", ["params_file", "launch_param_file"])
def test_an_alias_bomb_is_refused_by_the_executables(where, tmp_path, subprocess_env):
    """The 921-byte kind of file that took 7.3 GB: one line, exit 2, in seconds, small."""
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(ALIAS_BOMB)
    if where == "params_file":
        cmd = [sys.executable, "-m", "mems_scenarios.cli", "imu_noise", "--params-file", str(bomb)]
        cmd += ["--out", str(tmp_path / "x.mcap")]
    else:
        launch = tmp_path / "g.launch.yaml"
        launch.write_text(
            "launch:\n- node: {pkg: mems_emulator, exec: imu_node, name: imu, "
            f"param: [{{from: {bomb}}}]}}\n"
        )
        cmd = [sys.executable, "-m", "mems_scenarios.run_graph", str(launch)]
    # the child reports its own peak resident memory (VmHWM of its address space; rusage's
    # maxrss would include this test process's size, inherited through fork)
    report = (
        "import atexit, runpy, sys\n"
        "def peak():\n"
        "    line = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0]\n"
        "    sys.stderr.write('PEAK ' + line.split()[1] + '\\n')\n"
        "atexit.register(peak)\n"
        f"sys.argv = {cmd[2:]!r}\n"
        f"runpy.run_module({cmd[2]!r}, run_name='__main__')\n"
    )
    t0 = time.monotonic()
    run = subprocess.run(
        [sys.executable, "-c", report],
        env=subprocess_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    elapsed = time.monotonic() - t0
    lines = run.stderr.strip().splitlines()
    peak_mb = int(lines[-1].split()[1]) / 1024 if lines and lines[-1].startswith("PEAK") else 0
    assert run.returncode == 2 and peak_mb > 0, run.stderr[-2000:]
    assert len(lines) == 2 and "alias" in lines[0], run.stderr[-2000:]
    assert elapsed < 30 and peak_mb < 500, (elapsed, peak_mb)
