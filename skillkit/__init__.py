"""skillkit: contextual policy search, GP forward models, kernel embeddings and DMPs for robot
skill learning, after Kupcsik's thesis *Non-parametric Models and Contextual Policy Search for
More Efficient Robot Skill Generalization*."""

import os

# skillkit never renders through dm_control: keep it from probing for an OpenGL backend
os.environ.setdefault("MUJOCO_GL", "disable")

__version__ = "0.1.0"
__all__ = ["Trajectory", "as_generator", "__version__"]

# imported on first use (PEP 562): ``import skillkit`` does not import numpy
_LAZY = {"Trajectory": "skillkit.trajectory", "as_generator": "skillkit._validation"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'skillkit' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
