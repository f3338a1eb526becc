"""Task rollouts as plotly animations (Figs 3.2 and 3.8) with play/pause and a time slider: links
from the task's MuJoCo model, ball and racket from the trajectory's signals, each interpolated
on its own clock (:mod:`skillkit.viz.scenes`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from skillkit._validation import check_array, check_count, check_positive, check_type
from skillkit.trajectory import Trajectory
from skillkit.viz.plots import REFERENCE_WIDTH
from skillkit.viz.scenes import COLORS, interpolate, kinematic_points, signal_times, task_model

__all__ = [
    "MAX_FRAMES",
    "TABLE_TENNIS_CONTEXTS",
    "THROWING_TARGETS",
    "arm_link_points",
    "planar_link_points",
    "racket_rim",
    "table_tennis_animation",
    "throwing_animation",
]

MAX_FRAMES = 200
"""Most frames an animation may have (the HTML grows with each)."""
THROWING_TARGETS = np.array([[6.0, 1.0], [12.0, 1.0]])
"""The two targets of Fig. 3.2 (Sec. 3.4.1: s₁ = [6, 1] m, s₂ = [12, 1] m)."""
TABLE_TENNIS_CONTEXTS = np.array([[-5.8, 0.0, 2.5, 0.6, -0.3], [-5.0, 0.0, 2.25, 0.9, 0.3]])
"""Two contexts s = [v_x, v_y, v_z, b_x, b_y] for Fig. 3.8 (v_y = 0: the initial stroke, without
context gain, hits only balls coming straight down the table)."""

# bodies at the joints (ankle, knee, hip, shoulder; floor, shoulder, elbow, wrist), end site
_SKELETONS = {
    "planar": (("shin", "thigh", "torso", "arm"), "hand"),
    "table-tennis": (("platform", "upper_arm", "forearm", "hand"), "racket"),
}
_SHOT_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd")


def _rgb(name: str) -> str:
    r, g, b = COLORS[name]
    return f"rgb({r},{g},{b})"


def _model(task, kind: str):
    """The MuJoCo model of a ``task`` of ``kind`` ("throwing", "planar" or "table-tennis")."""
    from skillkit.tasks.balancing import Balancing
    from skillkit.tasks.planar import Throwing
    from skillkit.tasks.table_tennis import TableTennis

    classes = {"throwing": Throwing, "planar": (Throwing, Balancing), "table-tennis": TableTennis}
    return task_model(check_type(task, classes[kind], "task", f"a {kind} task"))


def _link_points(task, kind: str, q) -> np.ndarray:
    """World points (N, 5, 3) of the skeleton of ``kind`` per row of joint positions q."""
    model = _model(task, kind)
    q = check_array(q, "q", shape=(None, model.nq))
    bodies, site = _SKELETONS[kind]
    return kinematic_points(model, q, [model.body(b).id for b in bodies], [model.site(site).id])


def planar_link_points(task, q) -> np.ndarray:
    """Ankle, knee, hip, shoulder and hand of the planar 4-link robot (Appendix C.1) per row of
    joint angles q (N, 4), shape (N, 5, 2) in its plane (m): with θ_k = q_1 + … + q_k, joint
    k + 1 at Σ_{j≤k} l_j (sin θ_j, cos θ_j), the hand l_4 (−sin θ_4, −cos θ_4) beyond the shoulder.
    """
    return _link_points(task, "planar", q)[..., [0, 2]]


def arm_link_points(task, q) -> np.ndarray:
    """Skeleton of the table-tennis arm (Appendix C.3) per row of joint positions q (N, 8)
    ([base_x, base_y, shoulder yaw, shoulder pitch, upper-arm roll, elbow, forearm roll, wrist]):
    platform origin, shoulder, elbow, wrist and blade centre (site ``racket``), shape (N, 5, 3)."""
    return _link_points(task, "table-tennis", q)


def racket_rim(center, normal, radius: float, n: int = 16) -> np.ndarray:
    """Closed rim c + r (cos φ u + sin φ v), φ = 0 … 2π, u ⟂ v ⟂ n, of a disc blade with
    ``center``, ``normal`` (3,) (length > 0), shape (n + 1, 3) for ``n`` ≥ 3 (first = last)."""
    c = check_array(center, "center", shape=(3,))
    nv = check_array(normal, "normal", shape=(3,))
    length = float(np.linalg.norm(nv))
    if length == 0.0:
        raise ValueError("normal: expected a non-zero vector")
    nv = nv / length
    if int(n) < 3:
        raise ValueError(f"n: expected at least 3 rim points, got {n}")
    axis = np.eye(3)[int(np.argmin(np.abs(nv)))]  # the axis least aligned with n
    u = np.cross(nv, axis)
    u /= np.linalg.norm(u)
    v = np.cross(nv, u)
    phi = np.linspace(0.0, 2.0 * np.pi, int(n) + 1)
    phi[-1] = 0.0  # closed exactly
    return c + float(radius) * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)


def _check_input(task, trajectories, contexts, n_frames, frame_ms, n_states: int):
    """The rollouts (states (T, ``n_states``)), their checked contexts, n_frames, frame_ms."""
    if isinstance(trajectories, Trajectory):
        trajectories = [trajectories]
    if not isinstance(trajectories, Sequence) or not 0 < len(trajectories) <= len(_SHOT_COLORS):
        raise ValueError(f"trajectories: expected a sequence of 1 … {len(_SHOT_COLORS)} Trajectory")
    for i, tr in enumerate(trajectories):
        if check_type(tr, Trajectory, f"trajectories[{i}]", "a Trajectory").failed:
            msg = f"trajectories[{i}]: a failed rollout has nothing to show ({tr.message})"
            raise ValueError(msg)
    s = check_array(contexts, "contexts", shape=(len(trajectories), task.context_dim))
    s = np.stack([task.check_context(row, "contexts") for row in s])
    n_frames = check_count(n_frames, "n_frames", minimum=2)
    if n_frames > MAX_FRAMES:
        raise ValueError(f"n_frames: expected at most {MAX_FRAMES} frames, got {n_frames}")
    frame_ms = check_positive(frame_ms, "frame_ms")
    for i, tr in enumerate(trajectories):
        check_array(tr.states, f"trajectories[{i}].states", shape=(None, n_states))
    return list(trajectories), s, n_frames, frame_ms


def _check_signal(tr: Trajectory, i: int, key: str, shape: tuple) -> np.ndarray:
    if key not in tr.signals:
        msg = f"trajectories[{i}]: has no signal {key!r} (signals: {sorted(tr.signals)})"
        raise ValueError(msg)
    return check_array(tr.signals[key], f"trajectories[{i}].signals[{key!r}]", shape=shape)


def _clock(trajs: list, clocks: list, n_frames: int) -> np.ndarray:
    """``n_frames`` times from the first start to the last end of the rollouts and signals."""
    start = min(float(tr.times[0]) for tr in trajs)
    end = max(max(float(tr.times[-1]), float(t[-1])) for tr, t in zip(trajs, clocks, strict=True))
    if not np.isfinite(start) or not np.isfinite(end) or end <= start:
        raise ValueError(f"trajectories: expected an end after start = {start:g}, got {end:g}")
    return np.linspace(start, end, n_frames)


def _at(times: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Linear interpolation of ``values`` (T, ...) at each grid time (the viewer's rule)."""
    return np.stack([interpolate(times, values, t) for t in grid])


def _finish(fig, play: tuple, title: str, lines, body: float, margin: dict, legend, **layout):
    """Frames ``play`` = (grid, frame(k) -> data, animated traces, frame_ms, redraw, y), title
    with ``lines`` under it, layout, and play/pause buttons and a time slider at ``y``."""
    import plotly.graph_objects as go

    grid, frame, animated, frame_ms, redraw, y = play
    fig.frames = [go.Frame(name=str(k), data=frame(k), traces=animated) for k in range(len(grid))]
    sub = "<br>".join(lines)
    text = f"{title}<br><span style='font-size:12px'>{sub}</span>" if sub else title
    legend = {**legend, "yanchor": "top", "bgcolor": "rgba(255,255,255,0.7)", "font": {"size": 11}}
    fig.update_layout(
        title={"text": text, "x": 0.01, "xanchor": "left", "font": {"size": 15}},
        autosize=True,
        height=margin["t"] + body + margin["b"],
        margin={**margin, "autoexpand": True},
        legend=legend,
        **layout,
        template="plotly_white",
    )
    play = {
        "frame": {"duration": frame_ms, "redraw": redraw},
        "fromcurrent": False,  # from the start: a finished auto-play can be replayed
        "transition": {"duration": 0},
        "mode": "immediate",
    }
    still = {"frame": {"duration": 0, "redraw": redraw}, "mode": "immediate"}
    still["transition"] = {"duration": 0}
    buttons = [
        {"label": "▶", "method": "animate", "args": [None, play]},
        {"label": "❚❚", "method": "animate", "args": [[None], still]},
    ]
    menu = {
        "type": "buttons",
        "direction": "left",
        "showactive": False,
        "x": 0.0,
        "xanchor": "left",
        "y": y,
        "yanchor": "top",
        "pad": {"t": 0, "r": 10},
        "buttons": buttons,
    }
    now = {"prefix": "t = ", "suffix": " s", "xanchor": "right", "font": {"size": 12}}
    steps = [
        {"label": f"{t:.2f}", "method": "animate", "args": [[str(k)], still]}
        for k, t in enumerate(grid)
    ]
    slider = {
        "active": 0,
        "x": 0.2,
        "len": 0.8,
        "xanchor": "left",
        "y": y + 0.02,
        "yanchor": "top",
        "pad": {"t": 0, "b": 0},
        "currentvalue": now,
        "steps": steps,
    }
    fig.update_layout(updatemenus=[menu], sliders=[slider])
    return fig


def throwing_animation(
    task,
    trajectories,
    contexts,
    *,
    n_frames: int = 40,
    frame_ms: float = 100.0,
    title: str = "Throwing for two targets (Fig. 3.2)",
    subtitle: str = "",
):
    """The planar 4-link robot throwing, a panel per target on one clock (Fig. 3.2): links
    (:func:`planar_link_points`), ball, its path and the target s; the panel title gives s, the
    release time t_r and min_t ‖b_t − s‖ (``task.reward_terms``).

    ``trajectories`` are 1–4 non-failed rollouts of ``task`` (states (T, 8) = [q, q̇], signals
    ``ball`` (N, 2) and ``ball_times`` (N,)); ``contexts`` (len(trajectories), 2) their targets
    [x, y] (m); ``n_frames`` (2 … :data:`MAX_FRAMES`) frames "0", "1", … of ``frame_ms``
    milliseconds; ``subtitle`` a smaller line under the title.
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    _model(task, "throwing")
    trajs, s, n_frames, frame_ms = _check_input(task, trajectories, contexts, n_frames, frame_ms, 8)
    n = len(trajs)
    balls, ball_t = [], []
    for i, tr in enumerate(trajs):
        ball = _check_signal(tr, i, "ball", (None, 2))
        _check_signal(tr, i, "ball_times", (ball.shape[0],))
        balls.append(ball)
        ball_t.append(signal_times(tr, "ball"))
    grid = _clock(trajs, ball_t, n_frames)
    links = [planar_link_points(task, _at(tr.times, tr.states[:, :4], grid)) for tr in trajs]
    ball_at = [_at(bt, b, grid) for bt, b in zip(ball_t, balls, strict=True)]

    # extent: everything drawn, with a margin; equal scales in x and y
    every = np.vstack([*(lk.reshape(-1, 2) for lk in links), *balls, s])
    x0, x1 = float(every[:, 0].min()) - 0.6, float(every[:, 0].max()) + 0.6
    y0, y1 = min(-0.3, float(every[:, 1].min()) - 0.2), float(every[:, 1].max()) + 0.4
    panel_h = int(np.ceil((y1 - y0) * (REFERENCE_WIDTH - 60 - 20) / (x1 - x0)))
    gap, top, bottom = 42, 92 if subtitle else 72, 120
    plot_h = n * panel_h + (n - 1) * gap
    names = []
    for tr, si in zip(trajs, s, strict=True):
        t_r, cm = tr.info.get("release_time"), 100 * task.reward_terms(tr, si)["distance"]
        release = f", release t_r = {t_r:.3f} s" if t_r is not None else ""
        target = f"target s = [{si[0]:g}, {si[1]:g}] m"
        names.append(f"{target}{release}, closest ball–target {cm:.0f} cm")
    fig = make_subplots(
        rows=n, cols=1, subplot_titles=names, vertical_spacing=gap / plot_h if n > 1 else 0
    )
    animated = []
    for i in range(n):
        row, first = i + 1, i == 0
        quiet = {"hoverinfo": "skip", "row": row, "col": 1}
        fig.add_scatter(
            x=[x0, x1],
            y=[0, 0],
            mode="lines",
            line={"color": "rgb(150,140,120)", "width": 2},
            name="ground",
            showlegend=False,
            **quiet,
        )
        fig.add_scatter(
            **_xyz(balls[i]),
            mode="lines",
            line={"color": _rgb("ball"), "width": 1.5, "dash": "dot"},
            name="ball path",
            legendgroup="path",
            showlegend=first,
            **quiet,
        )
        fig.add_scatter(
            x=[s[i, 0]],
            y=[s[i, 1]],
            mode="markers",
            marker={"symbol": "x", "size": 13, "color": _rgb("target")},
            name="target s",
            legendgroup="target",
            showlegend=first,
            row=row,
            col=1,
        )
        animated += [len(fig.data), len(fig.data) + 1]
        fig.add_scatter(
            **_xyz(links[i][0]),
            mode="lines+markers",
            line={"color": "rgb(90,100,125)", "width": 6},
            marker={"size": 7, "color": "rgb(60,65,80)"},
            name="robot",
            legendgroup="robot",
            showlegend=first,
            **quiet,
        )
        fig.add_scatter(
            **_xyz(ball_at[i][:1]),
            mode="markers",
            marker={"size": 10, "color": _rgb("ball"), "line": {"width": 1, "color": "black"}},
            name="ball",
            legendgroup="ball",
            showlegend=first,
            **quiet,
        )
        axes = {"constrain": "domain", "row": row, "col": 1, "zeroline": False}
        fig.update_xaxes(range=[x0, x1], title_text="x (m)" if row == n else None, **axes)
        anchor = f"x{'' if row == 1 else row}"
        fig.update_yaxes(
            range=[y0, y1], scaleanchor=anchor, scaleratio=1, title_text="y (m)", **axes
        )

    def frame(k: int) -> list:
        xys = [xy for i in range(n) for xy in (links[i][k], ball_at[i][k : k + 1])]
        return [go.Scatter(**_xyz(xy)) for xy in xys]

    for annotation in fig.layout.annotations:
        annotation.font = {"size": 12}
    play = (grid, frame, animated, frame_ms, False, -(bottom - 55) / plot_h)
    margin = {"t": top, "b": bottom, "l": 60, "r": 20}
    legend = {"x": 0.99, "xanchor": "right", "y": 1.0}
    return _finish(fig, play, title, [subtitle] if subtitle else [], plot_h, margin, legend)


def _table_traces(go, tt) -> list:
    """Table top, its lines and the net (Appendix C.3's regulation table, +z up)."""
    hx, hy, z = tt.TABLE_LENGTH / 2, tt.TABLE_WIDTH / 2, tt.TABLE_HEIGHT
    quiet = {"showlegend": False, "hoverinfo": "skip"}
    quad = {"i": [0, 0], "j": [1, 2], "k": [2, 3], **quiet}
    top = go.Mesh3d(
        x=[-hx, hx, hx, -hx],
        y=[-hy, -hy, hy, hy],
        z=[z] * 4,
        color=_rgb("table"),
        opacity=0.85,
        name="table",
        flatshading=True,
        **quad,
    )
    # the edge, then (after a break) the centre line; z a hair above the top
    xs = [-hx, hx, hx, -hx, -hx, None, -hx, hx]
    lines = go.Scatter3d(
        x=xs,
        y=[-hy, -hy, hy, hy, -hy, None, 0.0, 0.0],
        z=[None if v is None else z + 0.002 for v in xs],
        mode="lines",
        line={"color": "white", "width": 3},
        **quiet,
    )
    ny, nz = hy + tt.NET_OVERHANG, z + tt.NET_HEIGHT
    net = go.Mesh3d(
        x=[0.0] * 4,
        y=[-ny, ny, ny, -ny],
        z=[z, z, nz, nz],
        color="rgb(235,235,235)",
        opacity=0.6,
        name="net",
        **quad,
    )
    return [top, lines, net]


def _xyz(a: np.ndarray) -> dict:
    """plotly's ``x``, ``y`` (and ``z``) of points (N, 2) or (N, 3)."""
    return {k: a[:, j] for j, k in enumerate("xyz"[: a.shape[1]])}


def table_tennis_animation(
    task,
    trajectories,
    contexts,
    *,
    n_frames: int = 40,
    frame_ms: float = 100.0,
    title: str = "Two table-tennis shots (Fig. 3.8)",
    subtitle: str = "",
):
    """Table-tennis shots overlaid in one 3-D scene (Fig. 3.8): table and net; per shot, in its
    own colour, the arm (:func:`arm_link_points`; dashed from the second on), the blade
    (:func:`racket_rim`), the ball and its path, the target b = s[3:5] and the landing point p
    (``info["landing_point"]``, reached by a straight segment at ``info["landing_time"]`` after
    the episode); the title lines give each shot's context, outcome and ‖b − p‖.

    ``trajectories`` are 1–4 non-failed rollouts (states (T, 16) = [q, q̇]; signals ``ball``,
    ``racket``, ``racket_normal`` (T, 3)); ``contexts`` (len(trajectories), 5) their
    s = [v_x, v_y, v_z, b_x, b_y]; the rest and the errors as for :func:`throwing_animation`.
    """
    import plotly.graph_objects as go

    from skillkit.tasks import table_tennis as tt

    model = _model(task, "table-tennis")
    trajs, s, n_frames, frame_ms = _check_input(
        task, trajectories, contexts, n_frames, frame_ms, 2 * model.nq
    )
    n = len(trajs)
    z_land = tt.TABLE_HEIGHT + task.ball.radius
    shots = []
    for i, tr in enumerate(trajs):
        T = tr.times.shape[0]
        ball = _check_signal(tr, i, "ball", (T, 3))
        racket = _check_signal(tr, i, "racket", (T, 3))
        normal = _check_signal(tr, i, "racket_normal", (T, 3))
        bt = signal_times(tr, "ball")
        p = np.asarray(tr.info.get("landing_point", ball[-1, :2]), dtype=np.float64)
        t_land = tr.info.get("landing_time")
        if t_land is not None and t_land > bt[-1] and tr.info.get("outcome") != "net":
            bt, ball = np.append(bt, t_land), np.vstack([ball, [p[0], p[1], z_land]])
        shots.append({"tr": tr, "ball": ball, "bt": bt, "racket": racket, "normal": normal, "p": p})
    grid = _clock(trajs, [sh["bt"] for sh in shots], n_frames)
    radius = task.ball.racket_radius
    for sh in shots:
        tr = sh["tr"]
        sh["arm"] = arm_link_points(task, _at(tr.times, tr.states[:, : model.nq], grid))
        sh["ball_at"] = _at(sh["bt"], sh["ball"], grid)
        c, nv = _at(tr.times, sh["racket"], grid), _at(tr.times, sh["normal"], grid)
        sh["rim"] = np.stack([racket_rim(ck, nk, radius) for ck, nk in zip(c, nv, strict=True)])

    fig = go.Figure(data=_table_traces(go, tt))
    animated, lines = [], []
    for i, (sh, si) in enumerate(zip(shots, s, strict=True)):
        color, shot = _SHOT_COLORS[i], f"shot {i + 1}"
        info = sh["tr"].info
        cm = 100 * float(np.linalg.norm(si[3:5] - sh["p"]))
        hit = info.get("hit_time")
        hit = f" (hit at {hit:.2f} s)" if hit is not None else ""
        ctx = f"v = [{si[0]:g}, {si[1]:g}, {si[2]:g}] m/s, b = [{si[3]:g}, {si[4]:g}] m"
        lines.append(f"{shot}: {ctx} → {info.get('outcome', '?')}{hit}, lands {cm:.0f} cm from b")
        group = {"legendgroup": f"shot{i + 1}", "showlegend": False}
        common = {**group, "hoverinfo": "skip"}
        fig.add_scatter3d(
            **_xyz(sh["ball"]),
            mode="lines",
            line={"color": color, "width": 2, "dash": "dot"},
            name=f"{shot} ball path",
            **common,
        )
        fig.add_scatter3d(
            x=[si[3], sh["p"][0]],
            y=[si[4], sh["p"][1]],
            z=[tt.TABLE_HEIGHT + 0.005] * 2,
            mode="markers",
            marker={"symbol": ["diamond", "circle-open"], "size": [7, 8], "color": color},
            name=f"{shot} target b, landing p",
            **group,
        )
        animated += [len(fig.data), len(fig.data) + 1, len(fig.data) + 2]
        fig.add_scatter3d(
            **_xyz(sh["arm"][0]),
            mode="lines+markers",
            line={"color": color, "width": 7, "dash": "solid" if i == 0 else "dash"},
            marker={"size": 3, "color": color},
            name=shot,
            **{**common, "showlegend": True},
        )
        fig.add_scatter3d(
            **_xyz(sh["rim"][0]),
            mode="lines",
            line={"color": color, "width": 6},
            name=f"{shot} racket",
            **common,
        )
        fig.add_scatter3d(
            **_xyz(sh["ball_at"][:1]),
            mode="markers",
            marker={"size": 5, "color": _rgb("ball"), "line": {"width": 2, "color": color}},
            name=f"{shot} ball",
            **common,
        )

    def frame(k: int) -> list:
        out = []
        for sh in shots:
            ball = sh["ball_at"][k]
            out += [go.Scatter3d(**_xyz(sh["arm"][k])), go.Scatter3d(**_xyz(sh["rim"][k]))]
            out.append(go.Scatter3d(x=[ball[0]], y=[ball[1]], z=[ball[2]]))
        return out

    half = (tt.TABLE_LENGTH / 2, tt.TABLE_WIDTH / 2 + tt.NET_OVERHANG, 0.0)
    drawn = [*(sh["arm"].reshape(-1, 3) for sh in shots), *(sh["ball"] for sh in shots)]
    every = np.vstack([*drawn, [[-half[0], -half[1], 0.0], half]])
    lo, hi = every.min(axis=0) - 0.15, every.max(axis=0) + 0.15
    lo[2] = 0.0
    ratio = (hi - lo) / (hi - lo).max() * 1.6
    if n > 1 and all(np.array_equal(sh["tr"].states, shots[0]["tr"].states) for sh in shots):
        lines.append(
            "the arms move alike (one stroke for all contexts: no context gain); later ones dashed"
        )
    head = 60 + 17 * (len(lines) + bool(subtitle))
    scene_h, bottom = 520, 90
    scene = {
        f"{a}axis": {"range": [lo[j], hi[j]], "title": {"text": f"{a} (m)"}, "autorange": False}
        for j, a in enumerate("xyz")
    }
    scene.update(
        aspectmode="manual",
        aspectratio={"x": ratio[0], "y": ratio[1], "z": ratio[2]},
        camera={
            "eye": {"x": -1.0, "y": -1.1, "z": 0.55},
            "center": {"x": -0.2, "y": 0.05, "z": -0.15},
        },
    )
    play = (grid, frame, animated, frame_ms, True, -(bottom - 50) / scene_h)
    margin = {"t": head, "b": bottom, "l": 10, "r": 10}
    legend = {"x": 0.01, "xanchor": "left", "y": 0.98}
    lines = ([subtitle] if subtitle else []) + lines
    return _finish(
        fig, play, title, lines, scene_h, margin, legend, scene=scene, uirevision="table-tennis"
    )
