"""Validation of ZeroMQ endpoints before a socket binds or connects to them.

ZeroMQ accepts some malformed endpoints without complaint (``tcp://127.0.0.1:99999``
binds another port), so every endpoint the software binds or connects goes through
:func:`check_endpoint` first. See docs/formats.md.
"""

from __future__ import annotations

import ipaddress
import logging
import re

log = logging.getLogger(__name__)

TRANSPORTS = ("tcp", "ipc", "inproc")
_LABEL = r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)"
_HOSTNAME = re.compile(rf"{_LABEL}(\.{_LABEL})*\.?")
_EXPECTED_TCP = ("tcp://HOST:PORT with HOST an IPv4 address, a bracketed IPv6 address, a "
                 "host name{star_host} and PORT an integer in 1..65535{star_port}")


def _fail(endpoint, what: str) -> ValueError:
    return ValueError(f"ZeroMQ endpoint {endpoint!r}: {what}")


def _is_loopback(host: str) -> bool:
    if host.lower() in ("localhost", "localhost."):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _check_tcp(endpoint: str, address: str, bind: bool) -> None:
    expected = _EXPECTED_TCP.format(star_host=" or * (every interface)" if bind else "",
                                    star_port=" or * (a free port)" if bind else "")
    host, sep, port = address.rpartition(":")
    if not sep or not host:
        raise _fail(endpoint, f"expected {expected}")
    if port == "*":
        if not bind:
            raise _fail(endpoint, "port '*' (a free port) can only be bound, not "
                        "connected to; expected PORT an integer in 1..65535")
    elif not (port.isascii() and port.isdigit()) or not 1 <= int(port) <= 65535:
        raise _fail(endpoint, f"port {port!r} is not an integer in 1..65535; expected "
                    f"{expected}")
    if host.startswith("[") and host.endswith("]"):
        try:
            ip = ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            raise _fail(endpoint, f"host {host!r} is not an IPv6 address; expected "
                        f"{expected}") from None
        literal = str(ip)
    elif host == "*":
        if not bind:
            raise _fail(endpoint, "host '*' (every interface) can only be bound; expected "
                        "the address of the publisher")
        literal = "*"
    else:
        try:
            literal = str(ipaddress.IPv4Address(host))
        except ValueError:
            if not (host.isascii() and len(host) <= 253 and _HOSTNAME.fullmatch(host)):
                raise _fail(endpoint, f"host {host!r} is not an address or host name; "
                            f"expected {expected}") from None
            literal = host
    if bind and not _is_loopback(literal):
        every = literal in ("*", "0.0.0.0", "::")
        log.warning("binding %s: %s; pings are reachable from other hosts (use "
                    "tcp://127.0.0.1:PORT to keep them on this machine)", endpoint,
                    "every network interface" if every else f"non-loopback address {host}")


def check_endpoint(endpoint: str, *, bind: bool) -> str:
    """Return ``endpoint`` if it is a well-formed ZeroMQ endpoint to bind (``bind=True``)
    or connect to; raise ValueError naming it and what was expected otherwise.

    Transports: ``tcp://HOST:PORT`` (PORT in 1..65535; when binding, ``*`` for a free
    port and HOST ``*`` for every interface), ``ipc://PATH``, ``inproc://NAME``. Binding
    a TCP address that is not loopback (127.0.0.0/8, ::1, localhost) logs a warning.
    """
    if not isinstance(endpoint, str):
        raise _fail(endpoint, f"expected a string, got {type(endpoint).__name__}")
    transport, sep, address = endpoint.partition("://")
    if not sep or transport not in TRANSPORTS:
        raise _fail(endpoint, f"unknown transport {transport if sep else endpoint!r}; "
                    f"expected one of {', '.join(t + '://' for t in TRANSPORTS)}")
    if not address or not address.isprintable() or address != address.strip():
        raise _fail(endpoint, f"expected a non-empty {transport} address without "
                    "surrounding spaces or control characters")
    if transport == "tcp":
        _check_tcp(endpoint, address, bind)
    return endpoint
