"""The sockets of a process, from /proc (what ``ss -tunap`` reads), for tests that check
that nothing listens or sends beyond the loopback interface."""

from __future__ import annotations

import ipaddress
import os
import socket
import struct
from pathlib import Path


def inet_sockets(pid: int) -> list[tuple[str, str]]:
    """(protocol, local address:port) of every IPv4/IPv6 UDP or TCP socket of a process."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:[") : -1])
    found = []
    for proto in ("udp", "udp6", "tcp", "tcp6"):
        table = Path(f"/proc/{pid}/net/{proto}")
        if not table.exists():
            continue
        for line in table.read_text().splitlines()[1:]:
            cols = line.split()
            if cols[9] not in inodes:
                continue
            host, port = cols[1].split(":")
            raw = bytes.fromhex(host)
            if len(raw) == 4:
                address = socket.inet_ntop(socket.AF_INET, raw[::-1])
            else:  # four host-order 32-bit words
                words = struct.unpack("<4I", raw)
                address = socket.inet_ntop(socket.AF_INET6, struct.pack(">4I", *words))
            found.append((proto, f"{address}:{int(port, 16)}"))
    return found


def is_loopback(address_port: str) -> bool:
    """True for a loopback address (IPv4, IPv6, or IPv4 mapped into IPv6)."""
    ip = ipaddress.ip_address(address_port.rsplit(":", 1)[0])
    return (getattr(ip, "ipv4_mapped", None) or ip).is_loopback


def process_tree(pid: int) -> list[int]:
    """``pid`` and every live descendant of it (children through ``/proc/*/stat``)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        parent = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(parent, []).append(int(entry.name))
    tree, todo = [], [pid]
    while todo:
        current = todo.pop()
        tree.append(current)
        todo.extend(children.get(current, []))
    return tree


def non_loopback_sockets(pid: int) -> list[tuple[int, str, str]]:
    """(pid, protocol, address:port) of each socket of ``pid``'s process tree bound beyond
    the loopback interface (0.0.0.0, [::] or a network address)."""
    found = []
    for member in process_tree(pid):
        try:
            sockets = inet_sockets(member)
        except OSError:  # the process ended meanwhile
            continue
        found += [(member, proto, a) for proto, a in sockets if not is_loopback(a)]
    return found
