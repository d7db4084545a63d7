"""schemathesis against the live service's own ``/openapi.json``: generated requests to every
route, valid and invalid, never get a 5xx, and every answer matches the documented status codes,
content types and response schemas."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from neuenh_service.api.app import create_app
from neuenh_service.api.settings import Settings
from jobspecs import tiny_spec
from live_api import running_server, wait_for

TOKEN = "schema-token"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    # Small limits, so a generated spec that passes validation is still a job that runs quickly.
    with running_server(tmp_path_factory.mktemp("openapi") / "data", api_token=TOKEN, max_samples=300,
                        max_epochs=2, max_candidates_per_round=12, max_request_bytes=50_000,
                        max_upload_bytes=50_000, shutdown_grace_s=5) as s:
        with s.client(headers={"Authorization": f"Bearer {TOKEN}"}) as c:  # a real job, so ids exist
            wait_for(c, c.post("/jobs", json=tiny_spec(max_rounds=1).model_dump(mode="json")).json()["id"])
        yield s


# The document the live server serves at /openapi.json (built without starting the app, so the
# test cases are known at collection time; schemathesis' lazy fixture loader fails on pytest 9).
schema = schemathesis.openapi.from_dict(create_app(Settings()).openapi())


def test_the_served_document_is_the_one_tested(server):
    import httpx

    assert httpx.get(server.url + "/openapi.json").json() == schema.raw_schema


@schema.auth()
class Bearer:
    """The service's token on every generated request (schemathesis also tries requests without)."""

    def get(self, case, context):
        return TOKEN

    def set(self, case, token, context):
        case.headers = {**(case.headers or {}), "Authorization": f"Bearer {token}"}


# Checks that cannot hold by design, per operation: a schema-valid job spec may still exceed the
# service's limits or name a position the model lacks, a schema-valid upload may not be a table, and a
# schema-valid scene may name files outside the data roots or give both tolerances (or, sent as text
# with its files, not be YAML at all).
SEMANTIC_422 = {("POST", "/v1/jobs"), ("POST", "/v1/jobs/{job_id}/fit"), ("POST", "/v1/plans"),
                ("POST", "/v1/plan-uploads")}


@schema.parametrize()
@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
def test_every_route_conforms_and_never_answers_5xx(case, server):
    excluded = ([schemathesis.checks.positive_data_acceptance]
                if (case.operation.method.upper(), case.operation.path) in SEMANTIC_422 else [])
    case.call_and_validate(base_url=server.url, excluded_checks=excluded)
