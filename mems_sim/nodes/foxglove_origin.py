"""Which web pages may open the live view: the rule on a WebSocket handshake's ``Origin``.

A browser sends the ``Origin`` of the page that opens a WebSocket, and any page may try to
open ``ws://127.0.0.1:8765``: without a check, a web page the user visits could read the
graph's stream. Allowed by default (:data:`DEFAULT_ORIGINS` and :func:`is_loopback_origin`):

- no ``Origin`` header: a program, not a browser page (the Foxglove desktop app, a script);
- ``null`` and ``file://...``: desktop apps and local files (Electron, a saved page);
- ``http(s)://`` on a loopback host (``localhost``, ``127.0.0.0/8``, ``[::1]``), any port;
- the Foxglove web app, ``https://app.foxglove.dev``.

Other origins are added by name (``scheme://host[:port]``, as a browser sends them; the
case of scheme and host does not matter). Everything else is refused.
"""

from __future__ import annotations

import ipaddress
from urllib.parse import urlsplit

#: Origins allowed without being named: the Foxglove web app, and ``null`` (sandboxed or
#: desktop pages).
DEFAULT_ORIGINS = ("https://app.foxglove.dev", "null")

#: Host names that are loopback by name.
LOOPBACK_NAMES = ("localhost",)


class OriginError(ValueError):
    """An origin a user named is not of the form ``scheme://host[:port]``."""


def normalize_origin(text: str) -> str:
    """``text`` as compared: trimmed, lower case, no trailing ``/``.

    Raises:
        OriginError: not ``null`` nor ``scheme://host[:port]`` (a path, query, user or an
            empty host).
    """
    origin = text.strip().lower().rstrip("/")
    if origin == "null":
        return origin
    try:
        parts = urlsplit(origin)
        _ = parts.port  # raises ValueError when the port is not a number
    except ValueError as exc:
        raise OriginError(f"{text!r} is not an origin ({exc})") from None
    if not parts.scheme or not parts.hostname or parts.path or parts.query or parts.fragment:
        raise OriginError(f"{text!r} is not an origin: expected scheme://host[:port]")
    if parts.username is not None or parts.password is not None:
        raise OriginError(f"{text!r} is not an origin: it names a user")
    return origin


def parse_origins(text: str) -> tuple[str, ...]:
    """The comma-separated origins of ``text``, normalized (an empty text: none).

    Raises:
        OriginError: an entry is not an origin (:func:`normalize_origin`).
    """
    return tuple(normalize_origin(t) for t in text.split(",") if t.strip())


def is_loopback_origin(origin: str) -> bool:
    """True for ``http(s)://`` with a loopback host (any port)."""
    try:
        parts = urlsplit(origin)
        host = parts.hostname
    except ValueError:
        return False
    if parts.scheme not in ("http", "https") or not host:
        return False
    if host in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class OriginPolicy:
    """The allowed origins of one server.

    Args:
        extra: origins the user adds (normalized, :func:`parse_origins`).
    """

    def __init__(self, extra: tuple[str, ...] = ()) -> None:
        self.allowed = frozenset(DEFAULT_ORIGINS) | frozenset(extra)

    def allows(self, origin: str | None) -> bool:
        """True when a handshake with this ``Origin`` header (None: none) is accepted."""
        if origin is None:
            return True
        text = origin.strip().lower()
        if text.startswith("file://"):
            return True
        text = text.rstrip("/")
        return text in self.allowed or is_loopback_origin(text)
