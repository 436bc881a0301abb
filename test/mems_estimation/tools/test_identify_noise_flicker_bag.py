"""End to end on a record the project did not generate: allantools' Kasdin & Walter
white + flicker + random-walk rate noise at known levels on 6 axes, written by rosbags as
``sensor_msgs/Imu`` in a rosbag2 MCAP bag, through the ``identify_noise`` command with
``--model auto --json``: every axis chooses the flicker floor, and N, B, K lie inside the
reported 95 % intervals on at least 5 of the 6 axes each."""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
from kasdin_records import kasdin_rate

from mems_estimation.tools.identify_noise import main

FS = 200.0
N_SAMPLES = 1 << 17
#: Allan coefficients N [u sqrt(s)], B [u], K [u/sqrt(s)]: the flicker floor meets the white
#: noise near tau = 0.2 s and the random walk near tau = 300 s.
LEVELS = (3e-4, 1e-3, 6e-5)


def write_bag(path, data: np.ndarray) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.LATEST)
    t = store.types
    Imu, Header, Time, Vec = (
        t["sensor_msgs/msg/Imu"],
        t["std_msgs/msg/Header"],
        t["builtin_interfaces/msg/Time"],
        t["geometry_msgs/msg/Vector3"],
    )
    quat = t["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0)
    cov = np.zeros(9)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store)
        for k, row in enumerate(data.tolist()):
            ns = 10**9 + k * 5_000_000
            msg = Imu(
                header=Header(stamp=Time(ns // 10**9, ns % 10**9), frame_id="imu"),
                orientation=quat,
                orientation_covariance=cov,
                angular_velocity=Vec(*row[:3]),
                angular_velocity_covariance=cov,
                linear_acceleration=Vec(*row[3:]),
                linear_acceleration_covariance=cov,
            )
            writer.write(conn, ns, store.serialize_cdr(msg, "sensor_msgs/msg/Imu"))


def test_flicker_record_through_identify_noise(tmp_path):
    data = np.column_stack([kasdin_rate(N_SAMPLES, FS, *LEVELS, seed=40 + j) for j in range(6)])
    write_bag(tmp_path / "bag", data)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(tmp_path / "bag"), "--model", "auto", "--json"])
    assert code == 0, err.getvalue()
    result = json.loads(out.getvalue())
    assert result["num_samples"] == N_SAMPLES
    assert math.isclose(result["sample_rate_hz"], FS, rel_tol=1e-9)
    choices = result["model_choice"]
    assert [c["model"] for c in choices] == ["flicker"] * 6
    for name, truth in zip(("N", "B", "K"), LEVELS):
        inside = [
            c["parameters"][name]["ci95"][0] <= truth <= c["parameters"][name]["ci95"][1]
            for c in choices
        ]
        assert sum(inside) >= 5, (name, inside)
