"""End-to-end: scenario imu_calibration (emulator on the multi_position profile ->
calibration node -> MCAP) against the emulator's truth, and calibrate_imu on its bag (the
same result offline; the same again from its samples as sensor_msgs/Imu in a bag rosbags
wrote; clear one-line errors on bad input)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from figure_checks import assert_figures

from mems_estimation.identification import imu_calibration_io as icio
from mems_scenarios import imu_calibration
from mems_scenarios.base import ScenarioOptions

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    from conftest import next_domain_id

    out = tmp_path_factory.mktemp("imucal") / "imu_calibration-3.mcap"
    return imu_calibration.run(
        ScenarioOptions(seed=3, out=out, domain_id=next_domain_id(), progress=False)
    )


def test_recording_and_figures(result):
    counts = result["recorder"]["counts"]
    for t in ("/imu/adc", "/imu/truth", "/imu/temperature_sensor"):
        assert counts[t] == 720, t  # 720 s at 100 Hz in 100-sample frames
    assert counts["/imu/calibration"] == 1 and counts["/imu/truth_calibration"] == 1
    assert all(g == 0 for g in result["recorder"]["gaps"].values())
    figs = assert_figures(result)
    print("\n" + result["table"])
    # one seed: the targets hold with margin (the campaign: test/acceptance)
    for name in (
        "gyro.scale_factor_error_rms",
        "accel.scale_factor_error_rms",
        "gyro.misalignment_error_rms",
        "accel.misalignment_error_rms",
        "accel.bias_error_rms",
        "gyro.bias_error_rms",
    ):
        assert figs[name]["pass"] is True, figs[name]
    assert figs["coverage.total"]["value"] == 33
    assert figs["coverage"]["value"] >= 0.8
    # the YAML the node wrote is the published calibration
    loaded = icio.load_yaml(result["yaml"])
    assert loaded.values["gyro_matrix_zz"] == result["calibration"].values["gyro_matrix_zz"]


def test_calibrate_imu_on_the_bag(result, tmp_path, subprocess_env):
    out = tmp_path / "cal.yaml"
    cmd = [str(BIN / "calibrate_imu"), str(result["mcap"]), "--profile", "multi_position"]
    run = subprocess.run(
        cmd + ["--noise", "adis16350", "--out", str(out), "--json"],
        capture_output=True,
        text=True,
        env=subprocess_env,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert "gyro_matrix_zz" in run.stderr and "+-95 %" in run.stderr
    d = json.loads(run.stdout)
    offline = {p["name"]: p["value"] for p in d["parameters"]}
    live = result["calibration"].values
    # the node used the temperature_sensor frames, the CLI the profile's 25 C: same values
    for n, v in offline.items():
        assert v == pytest.approx(live[n], rel=1e-9, abs=1e-12), n
    assert icio.load_yaml(out).values["accel_bias_x"] == pytest.approx(offline["accel_bias_x"])


def test_calibrate_imu_replaces_out_only_with_overwrite(result, tmp_path, subprocess_env):
    out = tmp_path / "cal.yaml"
    out.write_text("old\n")
    cmd = [str(BIN / "calibrate_imu"), str(result["mcap"]), "--profile", "multi_position"]
    cmd += ["--noise", "adis16350", "--out", str(out)]
    run = subprocess.run(cmd, capture_output=True, text=True, env=subprocess_env, timeout=120)
    assert run.returncode == 2 and "--overwrite" in run.stderr, run.stderr
    assert out.read_text() == "old\n"
    run = subprocess.run(
        cmd + ["--overwrite"], capture_output=True, text=True, env=subprocess_env, timeout=120
    )
    assert run.returncode == 0, run.stderr
    assert "gyro_matrix_zz" in icio.load_yaml(out).values
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml"]  # no temporary left


@pytest.mark.parametrize(
    "args, text",
    [
        (["{bag}", "--profile", "nope"], "neither a built-in"),
        (["{bag}", "--profile", "multi_position", "--topic", "/imu/truth"], "not AdcFrame"),
        (["{bag}", "--profile", "multi_position", "--noise", "x.json"], "noise model"),
        (["/nonexistent.mcap", "--profile", "multi_position"], "no such file"),
        (["{bag}", "--profile", "multi_position", "--base", "/nonexistent.yaml"], "cannot read"),
    ],
)
def test_calibrate_imu_bad_input(result, args, text, subprocess_env):
    cmd = [str(BIN / "calibrate_imu")] + [a.format(bag=result["mcap"]) for a in args]
    run = subprocess.run(cmd, capture_output=True, text=True, env=subprocess_env, timeout=60)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("calibrate_imu: error:"), run.stderr
    assert text in lines[0]


def _rosbags_imu_bag(frames, path: Path) -> Path:
    """The AdcFrames as sensor_msgs/Imu in a rosbag2 MCAP directory written by rosbags, not
    by this project: per sample the values a driver publishes (codes x LSB, float64), the
    stamp of the sample in sensor time (frame stamp + k / fs), orientation unknown."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from mems_sim.ros.frames import adc_physical, index_to_ns, time_to_ns

    store = get_typestore(Stores.LATEST)
    T, imu_type = store.types, "sensor_msgs/msg/Imu"
    zeros, unknown = np.zeros(9), np.array([-1.0] + [0.0] * 8)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/imu/data_raw", imu_type, typestore=store)
        for f in frames:
            values, t0 = adc_physical(f), time_to_ns(f.header.stamp)
            for k, v in enumerate(values.tolist()):
                t = index_to_ns(k, f.sample_rate_hz, t0)
                msg = T[imu_type](
                    header=T["std_msgs/msg/Header"](
                        stamp=T["builtin_interfaces/msg/Time"](*divmod(t, 10**9)), frame_id="imu"
                    ),
                    orientation=T["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
                    orientation_covariance=unknown,
                    angular_velocity=T["geometry_msgs/msg/Vector3"](*v[:3]),
                    angular_velocity_covariance=zeros,
                    linear_acceleration=T["geometry_msgs/msg/Vector3"](*v[3:]),
                    linear_acceleration_covariance=zeros,
                )
                writer.write(conn, max(t, 1), store.serialize_cdr(msg, imu_type))
    return path


def test_calibrate_imu_reads_a_rosbags_imu_bag(result, tmp_path):
    """calibrate_imu on sensor_msgs/Imu written by rosbags gives the calibration of the
    project's AdcFrame recording of the same samples. Both carry the same float64 values
    (the frames' codes x LSB are what the Imu messages hold); the Imu path rebuilds the
    sample indices from the stamps at the rate (n - 1) / span of the stamps, which the
    integer-ns stamps k / fs give as 100 Hz to ~1e-14: the same segments and samples, so
    the values and standard errors agree to 1e-9 relative (measured: bit-identical).
    To stay quick, the first 360 s of the recording (the six_position part of
    multi_position: accelerometer matrix and bias, gyro bias and g-sensitivity)."""
    import contextlib
    import io

    from mems_estimation.tools.calibrate_imu import main as calibrate_main
    from mems_sim.bag.player import read_messages

    frames = [m for _, _, _, m in read_messages(str(result["mcap"]), ["/imu/adc"])][:360]
    bag = _rosbags_imu_bag(frames, tmp_path / "imu_mcap")
    got = {}
    for label, path in (("frames", result["mcap"]), ("imu", bag)):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            args = [str(path), "--profile", "six_position", "--noise", "adis16350", "--json"]
            assert calibrate_main(args) == 0, err.getvalue()
        got[label] = json.loads(out.getvalue())
        assert got[label]["info"]["segments"] == 6, label
    assert "/imu/data_raw, 36000 samples at 100 Hz (0 missing" in err.getvalue()
    ref = {p["name"]: p for p in got["frames"]["parameters"]}
    imu = {p["name"]: p for p in got["imu"]["parameters"]}
    assert len(ref) == 24 and set(imu) == set(ref)  # 9 + 3 accel, 3 + 9 gyro
    for name, p in imu.items():
        for key in ("value", "standard_error"):
            assert p[key] == pytest.approx(ref[name][key], rel=1e-9, abs=1e-300), (name, key)
    assert got["imu"]["info"]["samples"] == got["frames"]["info"]["samples"]
