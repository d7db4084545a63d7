"""Bearer-token auth: every /v1 route but /health needs the token when NEUENH_API_TOKEN is set."""

from __future__ import annotations

import pytest

from neuenh_service.api.settings import Settings

TOKEN = "s3cret-token"


@pytest.fixture()
def server(live_server):
    return live_server(api_token=TOKEN)


@pytest.mark.parametrize("headers, code", [
    ({}, 401),
    ({"Authorization": "Bearer wrong"}, 401),
    ({"Authorization": f"Bearer {TOKEN}x"}, 401),
    ({"Authorization": f"Basic {TOKEN}"}, 401),
    ({"Authorization": f"Bearer {TOKEN}"}, 200),
], ids=["none", "wrong", "longer", "basic", "right"])
@pytest.mark.parametrize("method, path", [("GET", "/jobs"), ("GET", "/jobs/x/history"), ("POST", "/jobs/x/cancel")])
def test_auth_matrix(server, headers, code, method, path):
    with server.client() as c:
        r = c.request(method, path, headers=headers)
    if code == 200:
        assert r.status_code in (200, 404)  # through auth; /jobs/x does not exist
    else:
        assert r.status_code == 401 and r.headers["www-authenticate"].startswith("Bearer")
        assert "token" in r.json()["detail"]


def test_health_is_open(server):
    with server.client() as c:
        r = c.get("/health")
    assert r.status_code == 200 and r.json()["auth"] is True


def test_submit_needs_the_token(server):
    with server.client() as c:
        assert c.post("/jobs", json={}).status_code == 401  # auth before validation


def test_settings_from_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("NEUENH_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("NEUENH_PORT", "9001")
    monkeypatch.setenv("NEUENH_API_TOKEN", TOKEN)
    monkeypatch.setenv("NEUENH_MAX_EPOCHS", "7")
    s = Settings()
    assert (s.data_dir, s.port, s.max_epochs, s.host) == (tmp_path, 9001, 7, "127.0.0.1")
    assert s.api_token.get_secret_value() == TOKEN and TOKEN not in repr(s)


def test_a_body_is_not_read_before_auth(server):
    """Bodies were read before auth (issue 17, case 8): a JSON body without a token got 422 (its
    shape was checked), and a /fit upload of up to 64 MB was spooled to disk before the 401."""
    import socket

    with server.client() as c:
        r = c.post("/jobs", content=b"{not json", headers={"Content-Type": "application/json"})
        assert r.status_code == 401, r.text
    host, port = server.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port))) as sock:
        sock.sendall(b"POST /v1/jobs/x/fit HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; "
                     b"boundary=b\r\nContent-Length: 60000000\r\n\r\n--b\r\n")  # 60 MB promised, 6 bytes sent
        sock.settimeout(10)
        head = sock.recv(4096)
    assert head.startswith(b"HTTP/1.1 401"), head[:80]  # answered without waiting for the body
