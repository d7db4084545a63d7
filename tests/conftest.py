import os
from collections import Counter
from pathlib import Path

# One intra-op thread for the suite and every process it starts (CLI runs, `neuenh serve`, plan
# workers, Ray workers inherit the environment): the tests' tensors are small, and on a 2-core
# machine two OpenMP threads beside any other busy process spin instead of working —
# tests/cli/test_fit_cli.py took 173 s with torch's default of two threads and 71 s with one
# while a search shared the cores (docs/BENCHMARKS.md, "Fit threads"). Set before torch loads.
os.environ["OMP_NUM_THREADS"] = "1"
# torch.compile's on-disk cache (inductor's) inside the checkout, unless one is chosen: its default,
# /tmp/torchinductor_$USER, is shared by every checkout and process on the machine, and it reads back
# a kernel cached under another ATEN_CPU_CAPABILITY without noticing (stop 77: a cache written
# natively gave the compiled training step NaN losses under avx2, one written under avx2 aborted the
# process natively), so a suite would depend on what else ran here (docs/BENCHMARKS.md, "Test suite time").
os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(Path(__file__).resolve().parents[1] / ".inductor-cache"))

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _deterministic_threads():
    """Tests compare bit-identical results; keep the thread count fixed within a test."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


# The files that take longest, heaviest first (seconds of wall time summed over each file's tests in
# a full run of `make test`'s command, under the suite's own load, on a 2-core Zen 4 EPYC, stop 83:
# warm caches, except test_train.py's, whose compiled step compiles from nothing in a clean clone).
# `make test` hands files to its processes in collection order (--no-loadscope-reorder; xdist's own
# reorder puts files with the most tests first, which left test_compose's two tests to start near the
# end while another process sat idle): starting the longest first leaves only short files for the end.
HEAVIEST_FIRST = (
    "tests/api/test_shared_cluster.py",  # 81 s
    "tests/neuenh/test_train.py",  # ~74 s cold: 20 s warm, its compiled step 62 s cold instead of 8 s
    "tests/cli/test_client.py",  # 68 s
    "tests/workers/test_ray_cluster.py",  # 63 s, a cluster per test
    "tests/deploy/test_compose.py",  # 54 s
    "tests/cli/test_service_demo.py",  # 49 s
    "tests/api/test_dashboard.py",  # 45 s
    "tests/cli/test_search_cli.py",  # 44 s
    "tests/api/test_plans.py",  # 35 s
    "tests/neuenh/test_fit.py",  # 33 s
    "tests/cli/test_report_cli.py",  # 22 s
    "tests/cli/test_fit_cli.py",  # 22 s
    "tests/api/test_serve.py",  # 21 s
    "tests/neuenh/export/test_equals_specialized.py",  # 18 s
    "tests/neuenh/scene/test_planner.py",  # 17 s
    "tests/orchestrator/test_runner.py",  # 17 s
    "tests/api/test_hostile_service.py",  # 16 s
    "tests/deploy/test_scaling.py",  # 16 s
    "tests/api/test_roles.py",  # 16 s
    "tests/cli/test_export_cli.py",  # 14 s
    "tests/cli/test_scene_cli.py",  # 14 s
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
