"""skillkit: contextual policy search, GP forward models, kernel embeddings and DMPs for robot
skill learning, after Kupcsik's thesis *Non-parametric Models and Contextual Policy Search for
More Efficient Robot Skill Generalization*."""

import os

# skillkit never renders through dm_control (scenes go to viser), so unless the user chose an
# OpenGL backend, tell dm_control not to probe for one (avoids GLFW errors on headless hosts).
os.environ.setdefault("MUJOCO_GL", "disable")

from skillkit._validation import as_generator
from skillkit.trajectory import Trajectory

__version__ = "0.1.0"
__all__ = ["Trajectory", "as_generator", "__version__"]
