import pytest

from neuenh_service.orchestrator.runner import Orchestrator
from neuenh_service.storage import LocalArtifactStore, SQLiteJobStore
from neuenh_service.workers.inline import InlineExecutor


@pytest.fixture()
def stores(tmp_path):
    jobs = SQLiteJobStore(tmp_path / "jobs.sqlite")
    artifacts = LocalArtifactStore(tmp_path / "artifacts")
    yield jobs, artifacts
    jobs.close()


@pytest.fixture()
def orchestrator(stores):
    return Orchestrator(*stores, InlineExecutor())
