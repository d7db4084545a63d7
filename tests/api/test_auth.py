"""Bearer-token auth: every /v1 route but /health needs the token when NEUENH_API_TOKEN is set."""

from __future__ import annotations

import pytest

from api.settings import Settings

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
