"""Shared test configuration (the environment variables are set by the repository's root
conftest.py, which also reaches the notebook kernels)."""


def pytest_configure(config):
    """One torch thread for the whole run (the root conftest.py covers BLAS; torch may have
    been imported by a plugin before it was set)."""
    import torch

    torch.set_num_threads(1)
