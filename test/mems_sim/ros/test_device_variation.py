"""One device of a batch at a temperature, per emulator: the device tables' manufacturing
spreads and temperature coefficients, the nodes' ``device_seed`` / ``temperature_c`` and
temperature input, the nominal device unchanged, and ``run_scenario --device-seed
--temperature``."""

import math

import numpy as np
import pytest
from conftest import params, spin_until
from sensor_msgs.msg import Temperature

from mems_sim.devices import accelerometer, scanner_amdm
from mems_sim.devices import resonator as sd_resonator
from mems_sim.devices import scanner as micro_scanner
from mems_sim.params import draw_device
from mems_sim.ros.node_base import EmulatorNode

#: Spreads the acceptance figures use (uniform within the range): parameter -> half width.
FIXED_SPREADS = {
    "accelerometer": {"stiffness": 0.10, "gap": 0.05, "mass": 0.02, "damping": 0.20},
    "scanner": {"sense_c0": 0.20, "sense_theta0": 0.10},
}


def _nodes():
    from mems_sim.nodes.accelerometer_node import AccelerometerNode
    from mems_sim.nodes.resonator_node import ResonatorNode
    from mems_sim.nodes.scanner_amdm_node import ScannerAmdmNode
    from mems_sim.nodes.scanner_node import ScannerNode

    return {
        "accelerometer": AccelerometerNode,
        "scanner": ScannerNode,
        "scanner_amdm": ScannerAmdmNode,
        "resonator": ResonatorNode,
    }


TABLES = {
    "accelerometer": accelerometer.ACCEL_SPECS,
    "scanner": micro_scanner.SCANNER_SPECS,
    "scanner_amdm": scanner_amdm.AMDM_SPECS,
    "resonator": sd_resonator.RESONATOR_SPECS,
}
#: A parameter with a temperature coefficient per device and the coefficient [1/K].
TEMPCO = {
    "accelerometer": ("stiffness", -60e-6),
    "scanner": ("natural_freq_hz", -30e-6),
    "scanner_amdm": ("spring_constant", -60e-6),
    "resonator": ("f0_hz", -30e-6),
}


@pytest.mark.parametrize("device", sorted(TABLES))
def test_a_drawn_device_stays_within_its_spread(device):
    """Every spread and coefficient has a source; over 200 device seeds each drawn parameter
    stays within its uniform range, the others are not drawn; the acceptance spreads are the
    tables'."""
    specs = TABLES[device]
    nominal = {s.name: s.default for s in specs}
    spread = {s.name: s.spread for s in specs if s.spread is not None}
    assert spread and any(s.tempco is not None for s in specs)
    for s in specs:
        for v in (s.spread, s.tempco):
            assert v is None or len(v.source) > 10, s.name
    for name, width in FIXED_SPREADS.get(device, {}).items():
        assert (spread[name].kind, spread[name].width) == ("uniform", width), name
    rel = np.array(
        [
            [draw_device(specs, nominal, seed)[n] / nominal[n] - 1.0 for n in spread]
            for seed in range(200)
        ]
    )
    widths = np.array([spread[n].width for n in spread])
    assert np.all(np.abs(rel) <= widths * (1 + 1e-12))
    assert np.all(np.abs(rel).max(axis=0) > 0.8 * widths)  # the range is used
    drawn = draw_device(specs, nominal, 7)
    assert {n for n in nominal if drawn[n] != nominal[n]} == set(spread)


@pytest.mark.parametrize("device", sorted(TABLES))
def test_the_node_draws_the_same_device_and_moves_it_with_temperature(ros_context, device):
    """The same device seed gives the same device through the node (parameters read back);
    a user's explicit value is not drawn; ``temperature_c`` moves the coefficient's
    parameter by it, also while the node runs."""
    cls = _nodes()[device]
    specs = TABLES[device]
    name, coefficient = TEMPCO[device]
    keep = next(s.name for s in specs if s.spread is not None and s.name != name)
    nodes = []
    try:
        a, b = (
            cls(context=ros_context, drive_externally=True, parameter_overrides=params(**kw))
            for kw in ({"device_seed": 11}, {"device_seed": 11, keep: nominal_of(specs, keep)})
        )
        nodes += [a, b]
        assert a.get_parameter("device_seed").value == 11
        assert a.drawn == draw_device(specs, a.values_of(specs), 11)
        assert a.drawn[keep] != nominal_of(specs, keep)
        assert b.fixed_parameters == {keep} and b.drawn[keep] == nominal_of(specs, keep)
        assert all(b.drawn[n] == a.drawn[n] for n in a.drawn if n != keep)
        ref = a.reference_temperature_c
        hot = cls(
            context=ros_context,
            drive_externally=True,
            parameter_overrides=params(device_seed=11, temperature_c=ref + 10.0),
        )
        nodes.append(hot)
        assert hot.drawn[name] == pytest.approx(a.drawn[name] * (1 + coefficient * 10.0))
        assert device_value(hot, name) == pytest.approx(hot.drawn[name], rel=1e-12)
        from rclpy.parameter import Parameter

        a.step()
        result = a.set_parameters([Parameter("temperature_c", value=ref - 20.0)])[0]
        assert result.successful, result.reason
        assert device_value(a, name) == pytest.approx(
            b.drawn[name] * (1 - coefficient * 20.0), rel=1e-12
        )
        assert a.step() > 0
    finally:
        for n in nodes:
            n.destroy_node()


def nominal_of(specs, name):
    return next(s.default for s in specs if s.name == name)


def device_value(node, name):
    """The value the node's device runs with (its parameter dict)."""
    d = node.device
    return (d.p if hasattr(d, "p") else d.params)[name]


def test_a_temperature_message_moves_the_device(graph):
    """sensor_msgs/Temperature on the node's ``temperature`` input: temperature_c follows,
    the device moves; a temperature out of range is ignored with a warning."""
    from mems_sim.nodes.accelerometer_node import AccelerometerNode

    ctx, ex, probe = graph
    node = AccelerometerNode(context=ctx, drive_externally=True)
    ex.add_node(node)
    try:
        k0 = node.device.p["stiffness"]
        pub = probe.create_publisher(Temperature, "/accelerometer/temperature", 10)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0)
        for t in (500.0, 46.85):
            msg = Temperature()
            msg.temperature = t
            pub.publish(msg)
        assert spin_until(ex, lambda: node.p["temperature_c"] == 46.85)
        assert node.device.p["stiffness"] == pytest.approx(k0 * (1 - 60e-6 * 20.0), rel=1e-12)
        assert node.diag.counters.get("temperature_ignored") == 1
    finally:
        ex.remove_node(node)
        node.destroy_node()


@pytest.mark.parametrize("device", sorted(TABLES))
def test_the_nominal_device_is_todays(ros_context, device):
    """Device seed -1 at the reference temperature, set explicitly, is the device the node
    makes without them, and the device made from the table's defaults: one frame equal."""
    cls = _nodes()[device]
    makers = {
        "accelerometer": lambda: accelerometer.ForceRebalanceAccelerometer({}, seed=0),
        "scanner": lambda: micro_scanner.MicroScannerDevice({}, seed=0),
        "scanner_amdm": lambda: scanner_amdm.AmdmScannerDevice({}, seed=0),
        "resonator": lambda: sd_resonator.SdResonatorDevice({}, seed=0),
    }
    plain = cls(context=ros_context, drive_externally=True)
    ref = plain.reference_temperature_c
    explicit = cls(
        context=ros_context,
        drive_externally=True,
        parameter_overrides=params(device_seed=-1, temperature_c=ref),
    )
    try:
        frames = [d.step(200) for d in (plain.device, explicit.device, makers[device]())]
        for f in frames[1:]:
            for x, y in zip(arrays(frames[0]), arrays(f)):
                np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    finally:
        plain.destroy_node()
        explicit.destroy_node()


def arrays(frame) -> list:
    """The fields of a device's frame (a dataclass or a NamedTuple)."""
    return list(vars(frame).values()) if hasattr(frame, "__dict__") else list(frame)


def test_the_in_loop_filters_keep_the_nominal_model(ros_context):
    """The accelerometer's V_B and in-loop EKF, and the resonator's in-loop observer, are
    designed from the nominal device, the plant is the drawn one."""
    from mems_sim.nodes.accelerometer_node import AccelerometerNode
    from mems_sim.nodes.resonator_node import ResonatorNode

    acc = AccelerometerNode(
        context=ros_context,
        drive_externally=True,
        parameter_overrides=params(device_seed=3, mode="ekf_rebalance"),
    )
    res = ResonatorNode(
        context=ros_context, drive_externally=True, parameter_overrides=params(device_seed=3)
    )
    try:
        nominal = accelerometer.validate_params({"mode": "ekf_rebalance"})
        assert acc.device.v_b == accelerometer.bias_voltage(nominal)
        np.testing.assert_array_equal(
            acc.device.ekf_config.model, accelerometer.plant_vector(nominal, acc.device.v_b)
        )
        assert acc.device.p["stiffness"] != nominal["stiffness"]
        assert res.device.model.f0 == pytest.approx(nominal_of(TABLES["resonator"], "f0_hz"))
        assert res.device.params["f0_hz"] != res.device.model.f0
    finally:
        acc.destroy_node()
        res.destroy_node()


def test_every_emulator_node_has_one_device_seed_and_temperature():
    """No duplicate parameter: the stage keeps its own device_seed and temperature_c."""
    from mems_sim.nodes.imu_node import ImuNode
    from mems_sim.nodes.stage_node import StageNode
    from mems_sim.params import spec_table

    for cls in (*_nodes().values(), ImuNode, StageNode):
        assert issubclass(cls, EmulatorNode)
        table = spec_table(cls.SPECS)  # refuses duplicates
        assert table["device_seed"].min in (-1, 0)
        assert math.isfinite(table["temperature_c"].default)
    assert StageNode.TEMPERATURE_INPUT != "temperature"  # its output


def test_the_stage_follows_its_temperature_input(graph):
    from mems_sim.nodes.stage_node import StageNode

    ctx, ex, probe = graph
    node = StageNode(context=ctx, drive_externally=True)
    ex.add_node(node)
    try:
        pub = probe.create_publisher(Temperature, "/stage/temperature_input", 10)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0)
        msg = Temperature()
        msg.temperature = 35.7
        pub.publish(msg)
        assert spin_until(ex, lambda: node.device.temperature_c == 35.7)
        assert node.gyro.temperature_c == 35.7
    finally:
        ex.remove_node(node)
        node.destroy_node()


@pytest.mark.parametrize(
    "option, value, text",
    [
        ("--device-seed", "-1", "--device-seed = -1 is invalid: allowed [0, 2^62]"),
        ("--temperature", "200", "--temperature = 200.0 is invalid: allowed [-60, 150] C"),
        ("--temperature", "nan", "--temperature = nan is invalid"),
    ],
)
def test_run_scenario_refuses_a_bad_device_seed_or_temperature(capsys, option, value, text):
    from mems_scenarios.cli import main

    assert main(["imu_noise", option, value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and text in err[0]


def test_the_scenario_graph_draws_every_emulator_but_not_the_users_values(domain_id):
    """Graph: --device-seed/--temperature reach every emulator node; the scenario's values
    are its nominal device (drawn), the user's --set values are fixed; a scenario that sets
    the temperature itself refuses --temperature."""
    from mems_scenarios.base import Graph, ScenarioError
    from mems_sim.nodes.accelerometer_node import AccelerometerNode
    from mems_sim.ros.params_file import parse_set

    graph = Graph(
        domain_id,
        overrides=[parse_set("accelerometer.stiffness=2.5")],
        device_seed=4,
        temperature_c=30.0,
    )
    try:
        node = graph.node(AccelerometerNode, {"mass": 4e-9}, drive_externally=True)
        assert node.p["device_seed"] == 4 and node.p["temperature_c"] == 30.0
        assert node.fixed_parameters == {"stiffness"}
        assert node.drawn["stiffness"] == 2.5
        assert (
            node.drawn["mass"] == draw_device(accelerometer.ACCEL_SPECS, {"mass": 4e-9}, 4)["mass"]
        )
        assert graph.applied[("/accelerometer/accelerometer", "device_seed")] == (
            4,
            "--device-seed",
        )
        with pytest.raises(ScenarioError, match="sets temperature_c of node"):
            graph.node(AccelerometerNode, {"temperature_c": 20.0}, namespace="other")
    finally:
        graph.close()


@pytest.mark.parametrize("device", ["accelerometer", "scanner", "scanner_amdm", "resonator"])
def test_the_warm_up_leaves_the_device_untouched(ros_context, device):
    """A self-started node loads its kernels on a copy of its device before its first
    frame (``warm_kernels``): the node's own device then gives the same frames, bit for bit,
    as one that was not warmed."""
    cls = _nodes()[device]
    nodes = []
    try:
        warmed, cold = (
            cls(context=ros_context, drive_externally=True, parameter_overrides=params(seed=5))
            for _ in range(2)
        )
        nodes += [warmed, cold]
        assert warmed.warm_kernels()
        for n in (300, 7):
            a, b = warmed.device.step(n), cold.device.step(n)
            fields = vars(a) if hasattr(a, "__dict__") else a._asdict()
            for key, value in fields.items():
                other = getattr(b, key)
                if isinstance(value, np.ndarray):
                    np.testing.assert_array_equal(value, other, err_msg=key)
                else:
                    assert value == other or (value != value and other != other), key
    finally:
        for node in nodes:
            node.destroy_node()
