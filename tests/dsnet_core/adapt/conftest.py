"""One torch thread for the adaptation tests: the machines behave like one core, and extra threads
on a loaded machine only spin (a 13 s test took 175 s with two)."""

import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
