"""Idle and slow connections cannot hold the service's connection slots (issue 17, case 4): the
attack was 260 idle TCP connections, no token, no bytes, after which every request, ``/health``
included, got 503 for as long as they were held."""

from __future__ import annotations

import socket
import time

import httpx

from live_api import running_server


def idle_connections(url: str, n: int) -> list[socket.socket]:
    host, port = url.removeprefix("http://").split(":")
    return [socket.create_connection((host, int(port))) for _ in range(n)]


def read_response(sock: socket.socket) -> bytes:
    """One whole HTTP response (head and Content-Length body) from ``sock``."""
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(4096)
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(int(line.split(b":")[1]) for line in head.split(b"\r\n")
                  if line.lower().startswith(b"content-length"))
    while len(body) < length:
        body += sock.recv(4096)
    return head + b"\r\n\r\n" + body


def test_idle_connections_are_closed_and_health_stays_reachable(tmp_path):
    with running_server(tmp_path, head_timeout=2.0, max_connections=64) as server:
        idle = idle_connections(server.url, 80)  # more than max_connections, none sends a byte
        opened = time.monotonic()
        try:
            with httpx.Client(base_url=server.url, timeout=10) as client:
                # the slots fill as the server accepts them: the attack works (503 for everyone)
                while client.get("/v1/health").status_code != 503:
                    assert time.monotonic() - opened < 1.5, "the idle connections never filled the slots"
                    time.sleep(0.05)
                # freed once the head deadline (2 s) has closed them: polled, because a loaded machine
                # acts on the deadline late (a fixed look at 2.5 s failed once under a full make test)
                while client.get("/v1/health").status_code != 200:
                    assert time.monotonic() - opened < 2.0 + 10.0, "the idle connections still hold the slots"
                    time.sleep(0.1)
            for sock in idle:  # the server closed every idle one (EOF)
                sock.settimeout(5)
                assert sock.recv(1) == b""
        finally:
            for sock in idle:
                sock.close()


def test_a_slow_request_head_is_cut_but_a_keep_alive_client_is_not(tmp_path):
    with running_server(tmp_path, head_timeout=1.0) as server:
        (slow,) = idle_connections(server.url, 1)
        slow.sendall(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # the head never ends
        (after,) = idle_connections(server.url, 1)  # a complete request, then the next head hangs
        after.sendall(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert read_response(after).startswith(b"HTTP/1.1 200")
        after.sendall(b"GET /v1/health HTTP/1.1\r\n")
        with httpx.Client(base_url=server.url, timeout=10) as client:
            assert client.get("/v1/health").status_code == 200
            time.sleep(1.5)
            for sock in (slow, after):
                sock.settimeout(5)
                assert sock.recv(1) == b""
            # a keep-alive connection idle between requests for longer than the head deadline is
            # not cut (pollers reuse theirs; uvicorn's keep-alive timeout applies there)
            for _ in range(2):
                assert client.get("/v1/health").status_code == 200
                time.sleep(1.5)
            assert client.get("/v1/health").status_code == 200
        slow.close()
        after.close()


def test_a_slow_body_of_a_started_request_is_not_cut(tmp_path):
    """The deadline is for the head only: a body that trickles in (an upload on a slow network)
    is the request's, and it is answered."""
    with running_server(tmp_path, head_timeout=0.5) as server:
        (sock,) = idle_connections(server.url, 1)
        body = b'{"name": "x"}'
        sock.sendall(b"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                     b"Content-Length: %d\r\n\r\n" % len(body))
        for byte in body[:3]:
            time.sleep(0.4)  # 1.2 s in all, past the head deadline
            sock.sendall(bytes([byte]))
        sock.sendall(body[3:])
        sock.settimeout(10)
        assert read_response(sock).startswith(b"HTTP/1.1 422")  # answered (an invalid spec), not cut
        sock.close()
