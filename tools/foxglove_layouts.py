"""Write the Foxglove layouts of the devices: ``config/foxglove/<device>.json``.

One layout per device, in the layout format the Foxglove app imports and exports
(``configById`` with one entry per panel, ``layout`` a tree of splits naming them): a Plot of
the estimate against the truth, a Plot of the raw ADC codes, and the diagnostics summary.
Topics are those of the device's default namespace (its node executables and reference
bags); for a device run under another namespace (a scenario's ``/stage_d1``, ``/acc_pi_1g``)
``--namespace NS DEVICE`` prints the device's layout with its topics there. Plot paths take
element 0..k of a frame: the first sample of each frame (the live view forwards at most
``max_rate_hz`` frames per second, so a plot shows the frames' first samples, not every
sample).

Run with the venv's python after changing a device's topics (a test checks that the files
are what this script writes)::

    .venv/bin/python tools/foxglove_layouts.py                               # config/foxglove/
    .venv/bin/python tools/foxglove_layouts.py --namespace /stage_d1 stage > stage_d1.json
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "config" / "foxglove"

#: device -> (plot title, [(message path, label)]) of the estimate-vs-truth plot, and the
#: ADC channels plotted (path, label).
DEVICES: dict[str, dict] = {
    "scanner": {
        "estimate": (
            "mirror angle theta [rad]",
            [("/scanner/estimate.states[0]", "EKF theta"), ("/scanner/truth.data[0]", "truth")],
        ),
        "adc": [("/scanner/adc.codes[0]", "y_cap")],
    },
    "scanner_amdm": {
        "estimate": (
            "mirror angle theta [rad]",
            [
                ("/scanner_amdm/ekf/estimate.states[0]", "EKF theta"),
                ("/scanner_amdm/ukf/estimate.states[0]", "UKF theta"),
                ("/scanner_amdm/truth.data[0]", "truth"),
            ],
        ),
        "adc": [("/scanner_amdm/adc.codes[0]", "y_cap")],
    },
    "accelerometer": {
        "estimate": (
            "acceleration [m/s^2]",
            [
                ("/accelerometer/estimate.states[2]", "EKF acceleration"),
                ("/accelerometer/truth.data[0]", "truth"),
            ],
        ),
        "adc": [("/accelerometer/adc.codes[0]", "readout")],
    },
    "resonator": {
        "estimate": (
            "position [m]",
            [
                ("/resonator/estimate.states[0]", "observer position"),
                ("/resonator/truth.data[0]", "truth"),
            ],
        ),
        "adc": [("/resonator/adc.codes[0]", "sigma-delta bit")],
    },
    "stage": {
        "estimate": (
            "tilt angle [rad]",
            [
                ("/stage/estimate.states[0]", "EKF theta"),
                ("/stage/truth.data[0]", "truth theta_y"),
                ("/stage/truth.data[2]", "truth theta_x"),
            ],
        ),
        "adc": [
            (f"/stage/adc.codes[{i}]", name) for i, name in enumerate(("1A", "1B", "2A", "2B"))
        ],
    },
    "imu": {
        "estimate": (
            "angular rate, truth [rad/s]",
            [(f"/imu/truth.data[{i}]", f"gyro_{a}") for i, a in enumerate("xyz")],
        ),
        "adc": [(f"/imu/adc.codes[{i}]", f"gyro_{a}") for i, a in enumerate("xyz")],
    },
}


def plot(title: str, series: list[tuple[str, str]]) -> dict:
    """A Plot panel's config: one series per message path, on the header stamps."""
    return {
        "title": title,
        "paths": [
            {"value": path, "label": label, "enabled": True, "timestampMethod": "headerStamp"}
            for path, label in series
        ],
        "showLegend": True,
        "legendDisplay": "floating",
        "xAxisVal": "timestamp",
        "isSynced": True,
    }


def in_namespace(path: str, device: str, namespace: str | None) -> str:
    """A message path of ``device``'s default namespace ``/<device>`` moved to ``namespace``
    (None: kept)."""
    if namespace is None:
        return path
    return "/" + namespace.strip("/") + path.removeprefix("/" + device)


def layout(device: str, namespace: str | None = None) -> dict:
    """The layout of one device, its topics in ``namespace`` (None: the default one)."""
    spec = DEVICES[device]
    title, series = spec["estimate"]
    series = [(in_namespace(p, device, namespace), label) for p, label in series]
    adc = [(in_namespace(p, device, namespace), label) for p, label in spec["adc"]]
    ids = {"estimate": "Plot!estimate", "adc": "Plot!adc", "diag": "DiagnosticSummary!diag"}
    return {
        "configById": {
            ids["estimate"]: plot(title, series),
            ids["adc"]: plot("raw ADC codes", adc),
            ids["diag"]: {"topicToRender": "/diagnostics", "sortByLevel": True},
        },
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {
            "direction": "row",
            "first": {
                "direction": "column",
                "first": ids["estimate"],
                "second": ids["adc"],
                "splitPercentage": 60,
            },
            "second": ids["diag"],
            "splitPercentage": 70,
        },
    }


def render(device: str, namespace: str | None = None) -> str:
    """The file text of one device's layout (its topics in ``namespace``, None: default)."""
    return json.dumps(layout(device, namespace), indent=2) + "\n"


_NAMESPACE = re.compile(r"/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*/?")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--namespace", help="print DEVICE's layout with its topics in NAMESPACE")
    parser.add_argument("device", nargs="?", choices=sorted(DEVICES), help="with --namespace")
    args = parser.parse_args(argv)
    if (args.namespace is None) != (args.device is None):
        parser.error("--namespace and DEVICE go together")
    if args.namespace is not None:
        if not _NAMESPACE.fullmatch(args.namespace):
            parser.error(f"--namespace {args.namespace!r} is not a ROS namespace")
        sys.stdout.write(render(args.device, args.namespace))
        return 0
    OUT.mkdir(parents=True, exist_ok=True)
    for device in DEVICES:
        (OUT / f"{device}.json").write_text(render(device))
    print(f"wrote {len(DEVICES)} layouts to {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
