"""What ``serve`` checks before anything starts, each a one-line error."""

from __future__ import annotations

import socket

import pytest

from neuenh_service.api.server import _listen


def test_listening_socket_is_tcp_so_answers_are_not_delayed():
    # asyncio turns on TCP_NODELAY for accepted connections only on a socket that says IPPROTO_TCP;
    # without it every answer waited ~40 ms for a delayed ACK (44 ms vs 1.6 ms per request).
    sock = _listen("127.0.0.1", 0)
    try:
        assert sock.proto == socket.IPPROTO_TCP and sock.getsockname()[1] > 0
        sock.listen()
        client = socket.create_connection(sock.getsockname())
        accepted, _ = sock.accept()
        assert accepted.proto == socket.IPPROTO_TCP
        accepted.close(), client.close()
    finally:
        sock.close()


def test_busy_port_is_a_one_line_error():
    taken = _listen("127.0.0.1", 0)
    taken.listen()
    try:
        with pytest.raises(ValueError, match=r"cannot listen on 127\.0\.0\.1:\d+: Address already in use"):
            _listen("127.0.0.1", taken.getsockname()[1])
    finally:
        taken.close()
