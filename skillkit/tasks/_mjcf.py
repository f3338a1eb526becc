"""The MJCF preamble shared by the robot models (planar, hockey and table-tennis arms)."""

from __future__ import annotations

from dm_control import mjcf

from skillkit._validation import check_positive

GRAVITY = 9.81
"""g (m/s²) of every MuJoCo model; gravity acts along −z."""


def mjcf_root(
    model: str, timestep: float, *, geom_rgba=None, contacts: bool = True
) -> mjcf.RootElement:
    """An empty MJCF model: ``timestep`` (s), gravity along −z, semi-implicit Euler, radians,
    non-colliding geoms; ``contacts=False`` disables contact detection."""
    root = mjcf.RootElement(model=model)
    root.option.timestep = check_positive(timestep, "timestep")
    root.option.gravity = [0.0, 0.0, -GRAVITY]
    root.option.integrator = "Euler"
    root.compiler.angle = "radian"
    root.default.geom.contype = 0
    root.default.geom.conaffinity = 0
    if geom_rgba is not None:
        root.default.geom.rgba = list(geom_rgba)
    if not contacts:
        root.option.flag.contact = "disable"
    return root
