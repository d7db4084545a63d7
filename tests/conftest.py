import os

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
