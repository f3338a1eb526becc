"""Repository-wide pytest configuration: the notebooks under ``notebooks/`` are executed by
nbmake as part of ``python -m pytest``; their kernels inherit this environment, so every live
re-run in them uses the ``smoke`` scale (seconds) unless ``SKILLKIT_SCALE`` says otherwise, and
writes under ``SKILLKIT_RUNS``."""

import os
import shutil
import tempfile

os.environ.setdefault("SKILLKIT_SCALE", "smoke")
# The notebooks' live runs go to a fresh folder per test session, so checkpoints left in
# notebooks/runs/ by a user (or by older code) are neither resumed nor refused here.
_RUNS = tempfile.mkdtemp(prefix="skillkit-notebook-runs-")
os.environ.setdefault("SKILLKIT_RUNS", _RUNS)
os.environ.setdefault("MUJOCO_GL", "disable")  # headless: never probe for an OpenGL backend
os.environ.setdefault("MPLBACKEND", "Agg")
# The tests work on small matrices, where multi-threaded BLAS/OpenMP only adds overhead (5–25×
# slower on a loaded 2-core machine) and makes results depend on the thread count.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def pytest_unconfigure(config):
    shutil.rmtree(_RUNS, ignore_errors=True)
