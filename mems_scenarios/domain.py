"""ROS domain leases: one scenario graph per ROS domain on this machine.

Two graphs on one domain see each other's topics, so a recorder would record the other
graph's frames and an estimator would take them as its own. A graph of this package
therefore holds a lease on its domain for as long as it runs: an advisory lock
(``fcntl.flock``, released by the kernel when the process ends, however it ends) on
``<lease dir>/domain-<id>.lock``. The lease directory is ``$MEMS_DOMAIN_LEASE_DIR`` or
``<temp dir>/mems_emulator-domains`` (shared by every user of the machine, since DDS
domains are); the lock file names the holder (process id and command) for the refusal
message of the next one.

:func:`lease_default_domain` picks the domain of a run that was given none: the first
free one of :func:`free_domains` (:data:`DEFAULT_DOMAINS`, or the ranges of
``$MEMS_FREE_DOMAINS`` such as ``66-101``), starting at a place derived from the process
id so that concurrent runs rarely try the same one first. A test suite that hands its
tests domains of their own confines the runs it starts without one (a campaign's) to
other domains this way. A domain given explicitly is leased
as it is, or refused (:class:`DomainBusy`) when another graph holds it.

The lease only coordinates graphs of this package; a graph started otherwise (``ros2
run``, another tool) is found by the graph check of :mod:`mems_scenarios.base`.
"""

from __future__ import annotations

import errno
import fcntl
import os
import sys
import tempfile
from pathlib import Path

#: Domains a run may pick when given none: 1..101 without the Makefile's targets' own
#: (61-65), then 0 (the default domain of every ROS tool, so the last choice). Above 101
#: the ports Fast DDS derives from the domain leave the range it is guaranteed on Linux.
DEFAULT_DOMAINS: tuple[int, ...] = tuple(d for d in range(1, 102) if not 61 <= d <= 65) + (0,)


#: The variable naming the domains a run given none may pick: ``A-B`` ranges and single
#: ids, separated by commas, each in [0, :data:`MAX_FREE_DOMAIN`].
FREE_DOMAINS_VARIABLE = "MEMS_FREE_DOMAINS"

#: The highest domain :data:`FREE_DOMAINS_VARIABLE` may name (Fast DDS's ports of domain
#: 232 reach 65535).
MAX_FREE_DOMAIN = 232


def free_domains() -> tuple[int, ...]:
    """The domains :func:`lease_default_domain` may pick, in order of preference:
    ``$MEMS_FREE_DOMAINS`` if set (e.g. ``66-101`` or ``3,5,70-80``), else
    :data:`DEFAULT_DOMAINS`. A malformed value raises ValueError (one line)."""
    text = os.environ.get(FREE_DOMAINS_VARIABLE, "").strip()
    if not text:
        return DEFAULT_DOMAINS
    out: list[int] = []
    for part in text.split(","):
        first, dash, last = part.strip().partition("-")
        numbers = (first, last) if dash else (first, first)
        low, high = (int(n) if n.isascii() and n.isdigit() else -1 for n in numbers)
        if not 0 <= low <= high <= MAX_FREE_DOMAIN:
            raise ValueError(
                f"{FREE_DOMAINS_VARIABLE} = {text!r} is invalid: expected domain ids and "
                f"ranges A-B (0 <= A <= B <= {MAX_FREE_DOMAIN}) separated by commas"
            )
        out.extend(d for d in range(low, high + 1) if d not in out)
    return tuple(out)


#: Domains whose lease this process holds (a lock taken and not yet released).
_HELD: set[int] = set()


def held_domains() -> frozenset[int]:
    """The domains this process holds a lease on (pending ones included)."""
    return frozenset(_HELD)


class DomainBusy(RuntimeError):
    """The domain is leased by another graph (the message is one line)."""


def lease_dir() -> Path:
    """Directory of the lock files (created world-writable and sticky, like /tmp)."""
    path = Path(
        os.environ.get("MEMS_DOMAIN_LEASE_DIR")
        or Path(tempfile.gettempdir()) / "mems_emulator-domains"
    )
    if not path.is_dir():
        path.mkdir(parents=True, exist_ok=True)
        try:
            path.chmod(0o1777)
        except OSError:
            pass
    return path


def _holder_text() -> str:
    command = " ".join([Path(sys.argv[0]).name] + sys.argv[1:3]) if sys.argv else "python"
    return f"pid {os.getpid()}: {command}"


class DomainLease:
    """A held lease on one ROS domain (:meth:`release` ends it; so does process exit)."""

    def __init__(self, domain_id: int, fd: int | None, path: Path | None) -> None:
        self.domain_id = domain_id
        self._fd = fd
        self.path = path

    @classmethod
    def try_acquire(cls, domain_id: int) -> DomainLease | None:
        """The lease of ``domain_id``, or None when another graph holds it. Without a
        usable lease directory the lease is granted unlocked (the graph check remains)."""
        try:
            path = lease_dir() / f"domain-{int(domain_id)}.lock"
            flags = os.O_CREAT | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
            try:
                fd = os.open(path, os.O_RDWR | flags, 0o666)
            except PermissionError:  # another user's lock file: a read-only lock will do
                fd = os.open(path, os.O_RDONLY | flags)
        except OSError:
            return cls(domain_id, None, None)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return None
            return cls(domain_id, None, None)
        try:
            os.fchmod(fd, 0o666)
        except OSError:
            pass
        try:
            os.ftruncate(fd, 0)
            os.write(fd, (_holder_text() + "\n").encode())
        except OSError:
            pass
        _HELD.add(int(domain_id))
        return cls(domain_id, fd, path)

    @property
    def held(self) -> bool:
        """True while this lease holds a lock."""
        return self._fd is not None

    def release(self) -> None:
        """End the lease (idempotent)."""
        if self._fd is not None:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_UN)
            finally:
                os.close(self._fd)
                self._fd = None
                _HELD.discard(int(self.domain_id))


def holder(domain_id: int) -> str:
    """Who holds the lease of ``domain_id``, as written in its lock file ("" if unknown)."""
    try:
        text = (lease_dir() / f"domain-{int(domain_id)}.lock").read_text()
    except OSError:
        return ""
    return " ".join(text.split())[:200]


#: Leases taken by :func:`lease_default_domain` in this process and not yet handed to a
#: graph (:func:`lease_domain` takes them over).
_PENDING: dict[int, DomainLease] = {}


def lease_default_domain() -> int:
    """Lease the first free domain of :func:`free_domains` (from a pid-derived start; the
    last one of them is tried last) and return it; the lease waits in this process for
    :func:`lease_domain`. A malformed ``$MEMS_FREE_DOMAINS`` raises ValueError."""
    domains = free_domains()
    candidates = domains[:-1] or domains
    start = os.getpid() % len(candidates)
    for domain_id in dict.fromkeys(candidates[start:] + candidates[:start] + domains[-1:]):
        if domain_id in _PENDING:
            continue
        lease = DomainLease.try_acquire(domain_id)
        if lease is not None:
            _PENDING[domain_id] = lease
            return domain_id
    which = (
        f"${FREE_DOMAINS_VARIABLE} ({os.environ[FREE_DOMAINS_VARIABLE].strip()})"
        if domains is not DEFAULT_DOMAINS
        else "0..101 (except 61-65)"
    )
    raise DomainBusy(
        f"no free ROS domain: every one of {which} is leased by another graph (lock files "
        f"in {lease_dir()}); pass --domain-id"
    )


def lease_domain(domain_id: int) -> DomainLease:
    """The lease of ``domain_id`` for a graph: the one :func:`lease_default_domain` took,
    else a new one. Raises :class:`DomainBusy` (one line naming the holder) when another
    graph, in this process or another, holds it."""
    lease = _PENDING.pop(domain_id, None)
    if lease is not None:
        return lease
    lease = DomainLease.try_acquire(domain_id)
    if lease is None:
        who = holder(domain_id)
        raise DomainBusy(
            f"ROS domain {domain_id} is in use by another scenario graph"
            + (f" ({who})" if who else "")
            + "; its topics would mix with this run's: pass another --domain-id, or none "
            "(and no ROS_DOMAIN_ID) to have a free one chosen"
        )
    return lease
