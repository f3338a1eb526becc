"""Shared test configuration."""

import os

os.environ.setdefault("MUJOCO_GL", "disable")  # headless: never probe for an OpenGL backend
os.environ.setdefault("MPLBACKEND", "Agg")
# The tests work on small matrices, where multi-threaded BLAS/OpenMP only adds overhead (5–25×
# slower on a loaded 2-core machine) and makes results depend on the thread count.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def pytest_configure(config):
    """One torch thread for the whole run (the OMP variable above covers BLAS; torch may have
    been imported by a plugin before it was set)."""
    import torch

    torch.set_num_threads(1)
