"""The MJCF preamble shared by the robot models (planar, hockey and table-tennis arms)."""

from __future__ import annotations

from dm_control import mjcf

from skillkit._validation import check_positive

GRAVITY = 9.81
"""g (m/s²) of every MuJoCo model; gravity acts along −z."""


def mjcf_root(
    model: str, timestep: float, *, geom_rgba=None, contacts: bool = True
) -> mjcf.RootElement:
    """An empty MJCF model with the settings every task's robot shares.

    Time step ``timestep``, gravity −9.81 m/s² along z, MuJoCo's semi-implicit Euler
    integrator, angles in radians, and geoms that collide with nothing by default
    (``contype = conaffinity = 0``: contacts are simulated outside MuJoCo, in pymunk or
    the ball model, or not at all).

    Parameters
    ----------
    model : str
        Model name.
    timestep : float
        Physics time step (s), > 0.
    geom_rgba : sequence of 4 floats, optional
        Default geom colour.
    contacts : bool
        False also switches MuJoCo's contact detection off (``<flag contact="disable"/>``).

    Returns
    -------
    dm_control.mjcf.RootElement
    """
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
