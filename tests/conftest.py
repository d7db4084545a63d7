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


# The files that take longest, heaviest first (seconds of test time summed over each file's tests,
# `pytest -n 3 --dist loadfile --no-loadscope-reorder` on a quiet 2-core EPYC with an empty inductor
# cache, as in a clean clone, stop 41). `make test` hands files to its processes in collection order
# (--no-loadscope-reorder; xdist's own reorder puts files with the most tests first, which left
# test_compose's two tests to start near the end while another process sat idle): starting the
# longest first leaves only short files for the end.
HEAVIEST_FIRST = (
    "tests/cli/test_client.py",  # 107 s
    "tests/api/test_shared_cluster.py",  # 98 s
    "tests/api/test_dashboard.py",  # 44 s
    "tests/workers/test_ray_cluster.py",  # 41 s
    "tests/cli/test_service_demo.py",  # 36 s
    "tests/neuenh/test_train.py",  # 36 s (stop 42): its compiled step (one graph) compiles from nothing in a new checkout
    "tests/deploy/test_compose.py",  # 34 s alone (stop 42: 22 candidates a round, 67 before; 57 s in the suite then)
    "tests/neuenh/test_fit.py",  # 29 s
    "tests/api/test_plans.py",  # 28 s
    "tests/cli/test_export_cli.py",  # 28 s
    "tests/cli/test_fit_cli.py",  # 26 s
    "tests/cli/test_report_cli.py",  # 24 s
    "tests/cli/test_scene_cli.py",  # 20 s
    "tests/api/test_serve.py",  # 20 s
    "tests/orchestrator/test_runner.py",  # 20 s
)


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(items):
    """Every test has a node id of its own: ``make test`` runs under pytest-xdist, which schedules by
    node id and would run only one of the tests sharing one (see tests/api/conftest.py). Then the
    heaviest files first, each file's tests in their own order."""
    shared = sorted(node_id for node_id, n in Counter(item.nodeid for item in items).items() if n > 1)
    if shared:
        raise pytest.UsageError(f"tests share a node id, so pytest-xdist would run one of each: {shared}")
    rank = {path: i for i, path in enumerate(HEAVIEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))
