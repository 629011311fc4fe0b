"""One torch thread: the test machine is shared, and oversubscribed OpenMP threads run ~10x slower."""

import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    torch.set_num_threads(1)
