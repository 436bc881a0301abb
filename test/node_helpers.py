"""Helpers of the node tests that talk to emulators and estimators through real topics.

Shared by test/mems_sim/nodes/test_*_nodes.py: stepping an emulator frame by frame, waiting
for publishers to be matched, reading a node's status on /diagnostics, one-channel frames
and the refusal of an emulator parameter.  Import as ``from node_helpers import ...`` (the
folder test/ is on sys.path, as for ``conftest``).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import params, spin_until

from mems_sim.params import ParameterError
from mems_sim.ros.frames import make_adc_frame


def step_frames(ex, dev, n_frames: int) -> None:
    """Publish ``n_frames`` frames of the emulator ``dev`` (``dev.step()``), letting the
    executor ``ex`` deliver after each one."""
    for _ in range(n_frames):
        dev.step()
        ex.spin_once(timeout_sec=0.0)


def wait_matched(ex, *publishers) -> bool:
    """Spin ``ex`` until each publisher has exactly one subscription; True if they do."""
    return spin_until(ex, lambda: all(p.get_subscription_count() == 1 for p in publishers))


def status_values(status) -> dict[str, str]:
    """The key/value pairs of one ``diagnostic_msgs/DiagnosticStatus``."""
    return {kv.key: kv.value for kv in status.values}


def diagnostics_show(diags, name_prefix: str, check) -> bool:
    """True if a status on /diagnostics (``diags``: received ``DiagnosticArray`` messages)
    of a node whose name starts with ``name_prefix`` satisfies ``check(status)``."""
    return any(s.name.startswith(name_prefix) and check(s) for d in diags for s in d.status)


def one_channel_adc(first, codes, fs, *, bits, name, lsb, full_scale, unit="V"):
    """An ``AdcFrame`` of one channel: ``codes`` (n,) from sample index ``first`` at ``fs`` Hz."""
    return make_adc_frame(
        np.asarray(codes).reshape(-1, 1),
        first,
        fs,
        bits=bits,
        channel_names=[name],
        channel_units=[unit],
        lsb=[lsb],
        full_scale=[full_scale],
    )


def emulator_refuses(node_class, context, match: str, **overrides) -> None:
    """The emulator ``node_class`` (driven externally) refuses the parameter ``overrides``
    with a ParameterError whose message matches ``match``."""
    with pytest.raises(ParameterError, match=match):
        node_class(context=context, drive_externally=True, parameter_overrides=params(**overrides))
