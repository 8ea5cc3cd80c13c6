import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    """Torch on one thread: the machines share their cores (many threads thrash)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
