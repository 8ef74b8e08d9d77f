"""Loopback ports for tests: every test gets its own Zenoh network on 127.0.0.1."""

from __future__ import annotations

import socket


def pick_free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def free_endpoint() -> str:
    """``tcp/127.0.0.1:<port>`` on a port that is free now."""
    return f"tcp/127.0.0.1:{pick_free_port()}"
