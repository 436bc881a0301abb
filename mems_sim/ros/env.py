"""Process environment defaults for every executable of this package.

The graph stays on this machine unless the user says otherwise:

* ``ROS_AUTOMATIC_DISCOVERY_RANGE`` unset or empty counts as ``LOCALHOST`` (rcl alone
  would treat an empty value as ``SUBNET``); a user who wants a networked graph sets it
  explicitly (e.g. ``SUBNET``).
* In ``LOCALHOST`` mode with Fast DDS (the default middleware), the process gets the
  package's localhost Fast DDS profile (:data:`PROFILE_NAME`, found by
  :func:`localhost_profile_path`) through ``FASTDDS_DEFAULT_PROFILES_FILE``: UDP on the
  loopback interface only plus shared memory, discovery by unicast to 127.0.0.1 and no
  multicast, so that no socket of the graph is bound to 0.0.0.0 or to a network
  address. rmw_fastrtps, in its own ``LOCALHOST`` mode, adds an unrestricted UDP
  transport to whatever the profile configures (its send sockets are bound to 0.0.0.0
  and to each network address), so the range is handed to rmw_fastrtps as
  ``SYSTEM_DEFAULT`` ("use the middleware's configuration"), which is this profile.
  ``MEMS_EMULATOR_FASTDDS_PROFILE`` records the substitution, so that a child process
  started with this environment, or one whose range was set back to ``LOCALHOST`` or to
  another value, is treated the same way.
* The profile is not applied, and ``LOCALHOST`` is left to rmw_fastrtps, when the user
  configures Fast DDS themselves (``FASTDDS_DEFAULT_PROFILES_FILE`` set, or a
  ``DEFAULT_FASTDDS_PROFILES.xml`` in the working directory that Fast DDS would load),
  lists ``ROS_STATIC_PEERS`` or ``ROS_DISCOVERY_SERVER`` (which need network
  interfaces), or selects another middleware with ``RMW_IMPLEMENTATION``.

``ROS_DOMAIN_ID`` is checked by every executable that joins a graph
(:func:`domain_id_problem`): rcl reads it with C's ``strtoul`` and takes ``-1`` for
domain 0, ``010`` for domain 8 and ``0x10`` for 16, and a domain above
:data:`MAX_DOMAIN_ID` leaves Fast DDS without ports; such a value is refused in one line.

``AMENT_PREFIX_PATH`` falls back to the interpreter prefix, where the PyPI ROS 2 wheels
install their ament index, so that message definitions are found without sourcing a
setup script.
"""

import os
import sys
from pathlib import Path

#: The discovery range variable of rcl.
RANGE_VARIABLE = "ROS_AUTOMATIC_DISCOVERY_RANGE"
#: Fast DDS's variable naming an XML profile file loaded by every participant.
PROFILE_VARIABLE = "FASTDDS_DEFAULT_PROFILES_FILE"
#: Set to the profile's path when :func:`apply_defaults` applied it (see the module doc).
MARKER_VARIABLE = "MEMS_EMULATOR_FASTDDS_PROFILE"
#: File name of the localhost profile, in ``config/`` of the source tree and in
#: ``share/mems_emulator/config/`` of an install prefix.
PROFILE_NAME = "fastdds_localhost.xml"
#: Middleware implementations the profile is for ("" is the default, rmw_fastrtps_cpp).
FASTDDS_RMWS = ("", "rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")
#: Middleware implementations that map a domain to UDP ports as the DDSI-RTPS
#: specification's default port mapping does (port base 7400, domain gain 250).
RTPS_RMWS = (*FASTDDS_RMWS, "rmw_cyclonedds_cpp", "rmw_connextdds")
#: Largest ROS domain of an RTPS middleware: the mapping puts domain d on UDP ports
#: 7400 + 250 d + 0..11 (plus 2 per participant), which pass 65535 from d = 233 on.
MAX_DOMAIN_ID = 232


def localhost_profile_path() -> Path | None:
    """The localhost Fast DDS profile: the source tree's ``config/`` or, in an install,
    ``share/mems_emulator/config/`` under an ``AMENT_PREFIX_PATH`` prefix or the
    interpreter prefix; None if there is none."""
    candidates = [Path(__file__).resolve().parents[2] / "config" / PROFILE_NAME]
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    for prefix in [*prefixes, sys.prefix]:
        candidates.append(Path(prefix) / "share" / "mems_emulator" / "config" / PROFILE_NAME)
    return next((c for c in candidates if c.is_file()), None)


def _user_configures_fastdds() -> bool:
    """True if the environment or the working directory already configures Fast DDS's
    discovery or transports, or another middleware is selected."""
    env = os.environ
    if env.get(PROFILE_VARIABLE) or env.get("ROS_STATIC_PEERS"):
        return True
    if env.get("ROS_DISCOVERY_SERVER"):
        return True
    if env.get("RMW_IMPLEMENTATION", "") not in FASTDDS_RMWS:
        return True
    skip_cwd_file = env.get("SKIP_DEFAULT_XML_FILE", "").startswith("1")
    return not skip_cwd_file and Path("DEFAULT_FASTDDS_PROFILES.xml").is_file()


def apply_defaults() -> None:
    """Localhost-only discovery unless the user chose otherwise (an empty range counts as
    unset), the localhost Fast DDS profile in that case, and an ament prefix.

    Idempotent, and safe in a process whose parent already called it (see the module doc).
    """
    env = os.environ
    ours = env.pop(MARKER_VARIABLE, None)
    if ours is not None and env.get(PROFILE_VARIABLE) == ours:
        # undo this function's earlier substitution (in this process or a parent)
        del env[PROFILE_VARIABLE]
        if env.get(RANGE_VARIABLE) == "SYSTEM_DEFAULT":
            env[RANGE_VARIABLE] = "LOCALHOST"
    if not env.get(RANGE_VARIABLE, "").strip():
        env[RANGE_VARIABLE] = "LOCALHOST"
    if not env.get("AMENT_PREFIX_PATH"):
        env["AMENT_PREFIX_PATH"] = sys.prefix
    if env[RANGE_VARIABLE].strip().upper() != "LOCALHOST" or _user_configures_fastdds():
        return
    profile = localhost_profile_path()
    if profile is None:
        return
    env[PROFILE_VARIABLE] = env[MARKER_VARIABLE] = str(profile)
    env[RANGE_VARIABLE] = "SYSTEM_DEFAULT"


def domain_id_problem() -> str | None:
    """Why ``ROS_DOMAIN_ID`` cannot be used (one line), or None if it is unset, empty (rcl
    then uses domain 0) or a decimal integer in [0, :data:`MAX_DOMAIN_ID`] (any size with a
    middleware outside :data:`RTPS_RMWS`), without sign, leading zeros or spaces."""
    value = os.environ.get("ROS_DOMAIN_ID")
    if not value:
        return None
    rtps = os.environ.get("RMW_IMPLEMENTATION", "") in RTPS_RMWS
    allowed = f"a decimal integer in [0, {MAX_DOMAIN_ID}]" if rtps else "a decimal integer >= 0"
    why = ""
    if value.isascii() and value.isdigit() and (value == "0" or not value.startswith("0")):
        if not rtps or int(value) <= MAX_DOMAIN_ID:
            return None
        why = (
            " (the RTPS port mapping puts domain d on UDP ports 7400 + 250 d + 0..11: above "
            f"{MAX_DOMAIN_ID} they pass 65535)"
        )
    elif value.lstrip().startswith(("-", "+", "0")):
        why = " (rcl would read it as C's strtoul does: -1 as domain 0, 010 as 8, 0x10 as 16)"
    return f"ROS_DOMAIN_ID = {value!r} is invalid: allowed {allowed}{why}"


def localhost_only() -> bool:
    """True if the graph of this process is restricted to this machine (after
    :func:`apply_defaults`): ``LOCALHOST`` mode or the localhost Fast DDS profile."""
    env = os.environ
    if env.get(MARKER_VARIABLE) and env.get(PROFILE_VARIABLE) == env[MARKER_VARIABLE]:
        return True
    return env.get(RANGE_VARIABLE, "").strip().upper() == "LOCALHOST"
