"""Shared test configuration (the environment variables are set by the repository's root
conftest.py, which also reaches the notebook kernels)."""

import os


def pytest_configure(config):
    """Torch threads as OMP_NUM_THREADS says (1 unless set: the root conftest.py sets it by
    default and covers BLAS; torch may have been imported by a plugin before it was set), so
    that ``OMP_NUM_THREADS=2 pytest`` really runs the two-thread floating-point paths."""
    import torch

    torch.set_num_threads(max(1, int(os.environ.get("OMP_NUM_THREADS", "1") or 1)))
