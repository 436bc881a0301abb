"""cProfile every Python process started with this directory on ``PYTHONPATH`` and
``MEMS_PROFILE_DIR`` set: each writes ``<MEMS_PROFILE_DIR>/<role>-<pid>.prof`` at exit
(role: the module or script it runs). Used by ``bench/profile_graph.py`` for the graphs
run as separate processes (docs/profiles.md); nothing happens without the variable."""

import os

_out = os.environ.get("MEMS_PROFILE_DIR")
if _out and os.environ.get("_ROS_WHEELS_BOOTSTRAP_COMPLETE"):
    import atexit
    import cProfile
    import sys

    _argv = sys.orig_argv if hasattr(sys, "orig_argv") else sys.argv
    _role = "python"
    for _i, _a in enumerate(_argv[1:], 1):
        if _a == "-m" and _i + 1 < len(_argv):
            _role = _argv[_i + 1].rsplit(".", 1)[-1]
            break
        if _a.endswith(".py"):
            _role = os.path.basename(_a)[:-3]
            break
    _prof = cProfile.Profile()

    def _dump() -> None:
        _prof.disable()
        os.makedirs(_out, exist_ok=True)
        _prof.dump_stats(os.path.join(_out, f"{_role}-{os.getpid()}.prof"))

    atexit.register(_dump)
    _prof.enable()
