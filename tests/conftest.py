import os
from collections import Counter

# One intra-op thread for the suite and every process it starts (CLI runs, `neuenh serve`, plan
# workers, Ray workers inherit the environment): the tests' tensors are small, and on a 2-core
# machine two OpenMP threads beside any other busy process spin instead of working —
# tests/cli/test_fit_cli.py took 173 s with torch's default of two threads and 71 s with one
# while a search shared the cores (docs/BENCHMARKS.md, "Fit threads"). Set before torch loads.
os.environ["OMP_NUM_THREADS"] = "1"

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _deterministic_threads():
    """Tests compare bit-identical results; keep the thread count fixed within a test."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(items):
    """Every test has a node id of its own: ``make test`` runs under pytest-xdist, which schedules by
    node id and would run only one of the tests sharing one (see tests/api/conftest.py)."""
    shared = sorted(node_id for node_id, n in Counter(item.nodeid for item in items).items() if n > 1)
    if shared:
        raise pytest.UsageError(f"tests share a node id, so pytest-xdist would run one of each: {shared}")
