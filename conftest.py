"""Repository-wide pytest configuration: the notebooks under ``notebooks/`` are executed by
nbmake as part of ``python -m pytest``; their kernels inherit this environment, so every live
re-run in them uses the ``smoke`` scale (seconds) unless ``SKILLKIT_SCALE`` says otherwise."""

import os

os.environ.setdefault("SKILLKIT_SCALE", "smoke")
os.environ.setdefault("MUJOCO_GL", "disable")
os.environ.setdefault("MPLBACKEND", "Agg")
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
