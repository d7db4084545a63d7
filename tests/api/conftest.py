import pytest
from schemathesis.pytest.plugin import SchemathesisFunction

from live_api import live_server  # noqa: F401  (fixture)


@pytest.fixture()
def client(server):
    """An httpx client of the module's ``server`` fixture, based at ``/v1``."""
    with server.client() as c:
        yield c


def pytest_collection_modifyitems(items):
    """Give each schemathesis case the node id its name already has.

    schemathesis 4.32 names the case of each route ``test_…[GET /v1/jobs]``, but pytest 9.2 builds a
    node id from the bare function name and a parametrize call, which these cases lack, so all 17
    share one id. pytest-xdist schedules by node id: under ``make test`` (``-n``) 16 of the 17 route
    checks of ``test_openapi.py`` would silently not run. (pytest 8 ids already carry the suffix.)
    """
    for item in items:
        if isinstance(item, SchemathesisFunction) and "[" not in item.nodeid:
            operation = item.name[len(item.originalname) + 1:-1]  # inside test_…[…]
            item._id = item.parent.id.child(item.originalname).with_params(operation)
