"""Stage process of ``bench_stage_ekf.py --graph-processes``: ``stage_node`` in a
process of its own, paced by its own wall-clock timer (``PacedEmulator.start``), with
per-frame publish times.

Run:  python bench/paced_stage.py [--wait-subs=TOPIC:N,...] [--timeout=S]
                                  --ros-args -r __ns:=/stage_t1 -p frame_size:=20000 ...

bench/paced_device.py with the stage's node class (``MicroStageNode``): the node as its
executable runs it, its timer started once the subscribers of the graph are matched
(``--wait-subs``), the process ends once the schedule is published and acknowledged by
every subscriber, and one JSON line gives the timing (frames, samples, fs, t_first/t_last,
rtf, max_late_s, cpu_s, ...; the generic paced device process documents them).
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from paced_device import main

if __name__ == "__main__":
    raise SystemExit(main(node="mems_sim.nodes.stage_node:MicroStageNode"))
