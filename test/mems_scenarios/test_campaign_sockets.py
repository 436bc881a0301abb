"""What ``ss -ltnp`` shows during ``run_campaign --workers 2``: every socket of the
campaign's processes (the driver with Dask's scheduler and workers, the runs it starts) is on
loopback, sampled while the campaign runs. The default tier checks the local cluster itself
in process (test_campaign.py::test_local_cluster_listens_on_loopback_only); this is the
command end to end."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from proc_sockets import inet_sockets, non_loopback_sockets, process_tree

BIN = Path(sys.executable).parent
#: Sampling period of the process tree's sockets [s].
SAMPLE_S = 0.2


@pytest.mark.slow
def test_run_campaign_with_two_workers_listens_on_loopback_only(tmp_path, subprocess_env):
    cmd = [str(BIN / "run_campaign"), "imu_noise", "--duration", "70", "--seeds", "1"]
    cmd += ["--workers", "2", "--out", str(tmp_path / "c"), "--no-progress"]
    run = subprocess.Popen(
        cmd, env=subprocess_env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    exposed, most_tcp, most_processes = [], 0, 0
    deadline = time.monotonic() + 300
    while run.poll() is None and time.monotonic() < deadline:
        tree = process_tree(run.pid)
        exposed += non_loopback_sockets(run.pid)
        try:
            tcp = [s for s in inet_sockets(run.pid) if s[0].startswith("tcp")]
        except OSError:
            break  # the driver ended meanwhile
        most_tcp, most_processes = max(most_tcp, len(tcp)), max(most_processes, len(tree))
        time.sleep(SAMPLE_S)
    _, err = run.communicate(timeout=60)
    assert run.returncode == 0, err[-3000:]
    assert most_tcp >= 3, most_tcp  # Dask's scheduler and two worker HTTP servers were seen
    assert most_processes >= 2, most_processes  # and the run's own process
    assert exposed == [], exposed
