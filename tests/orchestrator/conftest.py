import pytest

from orchestrator.runner import Orchestrator
from storage import LocalArtifactStore, SQLiteJobStore
from workers.inline import InlineExecutor


@pytest.fixture()
def stores(tmp_path):
    jobs = SQLiteJobStore(tmp_path / "jobs.sqlite")
    artifacts = LocalArtifactStore(tmp_path / "artifacts")
    yield jobs, artifacts
    jobs.close()


@pytest.fixture()
def orchestrator(stores):
    return Orchestrator(*stores, InlineExecutor())
