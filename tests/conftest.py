import pytest
import torch


@pytest.fixture(autouse=True)
def _deterministic_threads():
    """Tests compare bit-identical results; keep the thread count fixed within a test."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)
