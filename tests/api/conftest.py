import pytest

from live_api import live_server  # noqa: F401  (fixture)


@pytest.fixture()
def client(server):
    """An httpx client of the module's ``server`` fixture, based at ``/v1``."""
    with server.client() as c:
        yield c
