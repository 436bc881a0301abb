"""Launch files generated from a scenario's graph (:meth:`GraphSpec.to_launch_yaml`): the
shipped file equals the one the scenario writes, and run_graph reads it."""

import subprocess
import sys
from pathlib import Path

import pytest

from mems_scenarios import load
from mems_scenarios.base import ScenarioOptions

REPO = Path(__file__).resolve().parents[2]
#: Shipped file -> (scenario, realtime factor of its emulators as processes).
GENERATED = {"sd_resonator.launch.yaml": ("sd_resonator", 0.05)}


def generated(scenario: str, realtime_factor: float) -> str:
    """The scenario's default graph (seed 0, default duration) for run_graph."""
    module = load(scenario)
    spec = module.graph(ScenarioOptions(), module.DEFAULT_DURATION_S)
    return spec.as_processes(realtime_factor).to_launch_yaml()


@pytest.mark.parametrize("name", sorted(GENERATED))
def test_shipped_launch_file_is_the_generated_one(name):
    text = (REPO / "launch" / name).read_text()
    assert text == generated(*GENERATED[name]), f"regenerate launch/{name}"


@pytest.mark.parametrize("name", sorted(GENERATED))
def test_run_graph_reads_the_generated_file(name, subprocess_env):
    module = load(GENERATED[name][0])
    spec = module.graph(ScenarioOptions(), module.DEFAULT_DURATION_S)
    run = subprocess.run(
        [str(Path(sys.executable).parent / "run_graph"), str(REPO / "launch" / name), "--dry-run"],
        env=subprocess_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    spaces = sorted(a for a in run.stdout.split() if a.startswith("__ns:="))
    assert spaces == sorted(f"__ns:=/{n.namespace}" for n in spec.nodes)
