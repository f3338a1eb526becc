"""Figures of results: no global matplotlib state, claim and verdict on the figure, band labels,
readable ranges when values run away, and the learning-curve and GP-fit helpers."""

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import plotly.graph_objects as go
import pytest
from matplotlib.figure import Figure

from skillkit.experiments.registry import Series
from skillkit.viz.figures import plot_gp_fit, plot_learning
from skillkit.viz.plots import (
    MAX_DECADES,
    matplotlib_figure,
    plotly_figure,
    robust_range,
    subtitle,
    write_figures,
)

ROOT = Path(__file__).resolve().parents[2]
CLAIM = "REPS learns within 5000 rollouts"
STATEMENT = "final reward -57 [-80, -34], thesis > -100 after 5000: holds"


def _result(series=None, summary=None, **extra) -> dict:
    series = series or [Series("a", [0, 1, 2], [1.0, 2.0, 3.0], panel="p").to_dict()]
    out = {"id": "figX", "title": "a test", "scale": "quick", "series": series, **extra}
    if summary is not None:
        out["summary"] = summary
    return out


def _plotly_title(fig) -> str:
    return fig.layout.title.text.replace("<br>", " ")


def _mpl_title(fig) -> str:
    return " ".join(fig.get_suptitle().split())


def _flat(text: str) -> str:
    return " ".join(text.split())


def _legend_texts(fig: Figure) -> list[str]:
    return [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]


# ------------------------------------------------------------------------ global state
def test_library_never_changes_the_matplotlib_backend(tmp_path):
    """Drawing, writing figures and a whole reproduce() keep the user's backend (a notebook's
    inline backend) and never import pyplot."""
    script = textwrap.dedent(
        f"""
        import sys
        import matplotlib
        matplotlib.use("svg")
        import skillkit
        from skillkit.experiments.registry import Series
        from skillkit.experiments.runner import reproduce
        from skillkit.viz.plots import matplotlib_figure, write_figures

        result = {{"id": "x", "title": "t", "series": [Series("a", [0, 1], [1, 2]).to_dict()]}}
        matplotlib_figure(result)
        write_figures(result, {str(tmp_path)!r}, html=False)
        folder = reproduce("fig2.10", scale="quick", seed=0, out={str(tmp_path)!r},
                           progress=False, html=False)
        assert (folder / "figure.png").read_bytes()[:4] == b"\\x89PNG"
        print(matplotlib.get_backend(), matplotlib.rcParams["backend"],
              "matplotlib.pyplot" in sys.modules)
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["svg", "svg", "False"]


def test_write_figures_writes_png_and_html(tmp_path):
    summary = {"claim": CLAIM, "verdict": "holds", "statement": STATEMENT}
    html, png = write_figures(_result(summary=summary), tmp_path)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert html is not None and "final reward -57 [-80, -34]" in html.read_text()
    html, png = write_figures(_result(), tmp_path, html=False)
    assert html is None and png.exists()


def test_matplotlib_figure_shows_itself_in_notebooks_without_pyplot():
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    fig = matplotlib_figure(_result())
    assert isinstance(fig, Figure) and plt.get_fignums() == before  # not a pyplot figure
    assert fig._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"  # what Jupyter displays
    assert isinstance(plotly_figure(_result()), go.Figure)


# --------------------------------------------------------------------- claim and verdict
@pytest.mark.parametrize("word", ["holds", "does not hold", "undecided", "not judged"])
def test_the_verdict_line_is_the_subtitle_and_the_claim_stays_out(word):
    """A figure carries one line of verdict (the card's second line); the claim and the details
    stay in the run's card, never in a figure title."""
    r = _result(summary={"claim": CLAIM, "verdict": word, "statement": STATEMENT})
    for title in (_plotly_title(plotly_figure(r)), _mpl_title(matplotlib_figure(r))):
        flat = _flat(title)
        assert "figX: a test (quick)" in flat and STATEMENT in flat
        assert CLAIM not in flat and "Thesis:" not in flat
    assert subtitle(r) == STATEMENT


def test_a_summary_without_a_verdict_line_shows_its_outcome_or_says_none_is_recorded():
    assert subtitle(_result(summary={"claim": CLAIM, "verdict": "undecided"})) == "undecided"
    r = _result(summary={"final": 3.0})
    assert subtitle(r) == "no verdict recorded"
    assert "no verdict recorded" in _flat(_mpl_title(matplotlib_figure(r)))


def test_results_without_a_claim_get_no_subtitle():
    r = _result()  # e.g. a learning curve or a comparison of two runs
    assert subtitle(r) == ""
    assert "<span" not in plotly_figure(r).layout.title.text


def test_subtitle_is_wrapped_to_the_width():
    r = _result(summary={"verdict": "does not hold", "statement": "number " * 30})
    lines = subtitle(r, width=60).splitlines()
    assert len(lines) > 2 and max(len(line) for line in lines) <= 60
    # a 760 px wide plotly title holds ~110 characters of 12 px text per line
    text = re.sub("<[^>]*>", "\n", plotly_figure(r).layout.title.text)
    sub_lines = [line for line in text.splitlines()[1:] if line]
    assert len(sub_lines) >= 2 and max(len(line) for line in sub_lines) <= 130


# ------------------------------------------------------------------------------ bands
def _banded(band_a, band_b=None):
    x = [0.0, 1.0, 2.0]
    return _result(
        [
            Series("a", x, [1, 2, 3], panel="p", lower=[0, 1, 2], upper=[2, 3, 4], band=band_a),
            Series("b", x, [3, 2, 1], panel="p", lower=[2, 1, 0], upper=[4, 3, 2], band=band_b),
        ]
    )


def test_one_band_description_gets_one_legend_entry():
    r = _banded("mean ± std over 20 trials", "mean ± std over 20 trials")
    names = [t.name for t in plotly_figure(r).data if t.showlegend is not False]
    assert names.count("shaded: mean ± std over 20 trials") == 1
    assert _legend_texts(matplotlib_figure(r)).count("shaded: mean ± std over 20 trials") == 1


def test_different_band_descriptions_are_named_per_series():
    r = _banded("mean ± std over 20 trials", "95% interval of the mean")
    expected = {"a: shaded mean ± std over 20 trials", "b: shaded 95% interval of the mean"}
    legend = {t.name for t in plotly_figure(r).data if t.showlegend is not False}
    assert expected <= legend
    assert expected <= set(_legend_texts(matplotlib_figure(r)))


def test_an_undescribed_band_is_drawn_but_not_explained():
    r = _banded(None)
    fig = plotly_figure(r)
    assert any(t.fill == "toself" for t in fig.data)
    assert not any("shaded" in (t.name or "") and t.showlegend is not False for t in fig.data)
    assert not any("shaded" in t for t in _legend_texts(matplotlib_figure(r)))


def test_band_is_a_series_field_dropped_when_absent():
    assert Series("a", [0], [1], lower=[0], upper=[2], band="95% interval").to_dict()["band"] == (
        "95% interval"
    )
    assert "band" not in Series("a", [0], [1]).to_dict()


# ------------------------------------------------------------------------------ ranges
def _runaway(log=True):
    """Like fig5.6: errors of 1e2..1e12, three runaway values up to 1e40, and a floor."""
    x = [2, 5, 10, 15, 20]
    common = {"panel": "error", "log_y": log, "ylabel": "e_r", "kind": "lines+markers"}
    return _result(
        [
            Series("gp", x, [1e12, 4e9, 2e11, 5e11, 1e12], **common),
            Series("step", x, [1e4, 3e40, 2e33, 2e6, 9e19], **common),
            Series("traj", x, [1e9, 6e8, 1.8e4, 1.8e4, 1.8e4], **common),
            Series("floor", x, [180.0] * 5, **{**common, "kind": "line"}),
        ],
        summary={"claim": CLAIM, "holds": False},
    )


def test_runaway_log_values_get_a_bounded_axis_and_a_note():
    r = _runaway()
    fig = plotly_figure(r)
    lo, hi = fig.layout.yaxis.range  # log10 units
    assert 12 < hi < 13.5 and 1 < lo < 2.3  # keeps 1.8e2 .. 1e12, not 1e40
    notes = [a.text for a in fig.layout.annotations if "above" in a.text]
    assert len(notes) == 1 and "3 values above" in notes[0] and "max 3e40" in notes[0]
    edge = [t for t in fig.data if "(off scale)" in (t.name or "")]
    assert sorted(x for t in edge for x in t.x) == [5, 10, 20]
    assert all(y == pytest.approx(10**hi) for t in edge for y in t.y)

    mfig = matplotlib_figure(r)
    ax = mfig.axes[0]
    bottom, top = ax.get_ylim()
    assert top == pytest.approx(10**hi) and top < 1e14 and bottom > 10
    assert any("3 values above" in t.get_text() for t in ax.texts)


def test_runaway_linear_values_are_clipped_below():
    y = np.linspace(-2.0, -0.1, 50)
    y[[10, 30]] = -1e12  # two diverged simulations
    r = _result([Series("reward", list(range(50)), y.tolist(), panel="p")])
    rng = robust_range(y, log=False)
    assert rng is not None and rng.lo == pytest.approx(-2.0) and rng.hi == pytest.approx(-0.1)
    assert rng.clipped(y)[1].sum() == 2 and rng.clipped(y)[0].sum() == 0
    a, b = plotly_figure(r).layout.yaxis.range
    assert -3 < a < -2 and -0.1 < b < 0.1
    assert any("2 values below" in t.get_text() for t in matplotlib_figure(r).axes[0].texts)


@pytest.mark.parametrize(
    "values, log",
    [
        (np.logspace(0, -15, 100), True),  # a converging curve: many decades, no outlier
        (10 ** np.array([1.3, 2.6, 2.5, 2.9, 4.1, 3.8, 5.9, 7.9, 2.8, 10.3]), True),  # fig4.5
        (10 ** np.r_[np.zeros(6), np.full(6, 20.0)], True),  # half the values: the data
        (np.r_[np.linspace(-0.2, -0.01, 30), np.full(70, -0.0086)], False),  # fig3.7-like
        (np.array([1.0, 1.0, 1.0, 0.9, 1.0]), False),
    ],
)
def test_ordinary_spreads_are_not_clipped(values, log):
    assert robust_range(values, log) is None


def test_a_forty_decade_spread_is_bounded():
    values = np.r_[np.logspace(1, 4, 30), [1e40, 1e35]]
    rng = robust_range(values, log=True)
    assert rng is not None and rng.hi == pytest.approx(1e4)
    assert np.log10(rng.axis[1] / rng.axis[0]) < MAX_DECADES
    assert rng.clipped(values)[0].sum() == 2


def test_axis_labels_come_from_the_series():
    r = _result([Series("a", [0, 1], [1, 2], xlabel="time [s]", ylabel="torque [N m]")])
    assert plotly_figure(r).layout.xaxis.title.text == "time [s]"
    ax = matplotlib_figure(r).axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("time [s]", "torque [N m]")


@pytest.mark.parametrize(
    "result, match",
    [([], "result"), ({"series": []}, "series"), ({"series": [{"name": "a"}]}, "series\\[0\\]")],
)
def test_bad_results_raise(result, match):
    with pytest.raises(ValueError, match=match):
        plotly_figure(result)
    with pytest.raises(ValueError, match=match):
        matplotlib_figure(result)


# ---------------------------------------------------------------------- learning curves
def _learn_like(offset=0.0, n=4, per=5):
    return {
        "rollouts": per * np.arange(n + 1),
        "mean_reward": -10.0 / (1 + np.arange(n + 1)) + offset,
        "explore_rollouts": per * np.arange(1, n + 1),
        "explore_reward": -12.0 / (1 + np.arange(n)) + offset,
        "policy": object(),
    }


def test_plot_learning_draws_a_real_learn_result():
    from skillkit.experiments.sanity import LinearOptimumTask
    from skillkit.search.loop import learn
    from skillkit.search.reps import ContextualREPS

    task = LinearOptimumTask()
    res = learn(task, ContextualREPS(task.initial_policy(), 1.0), 3, 20, 0)
    fig = plot_learning(res, label="REPS")
    line = next(t for t in fig.data if t.name == "REPS")
    np.testing.assert_array_equal(line.x, [0, 20, 40, 60])
    np.testing.assert_allclose(line.y, res["mean_reward"])
    dots = next(t for t in fig.data if t.name == "REPS: exploration batches")
    assert dots.mode == "markers"
    np.testing.assert_allclose(dots.y, res["explore_reward"])


def test_plot_learning_over_runs_draws_mean_and_band():
    runs = [_learn_like(o) for o in (-1.0, 0.0, 1.0)]
    fig = plot_learning(runs, label="REPS")
    mean = next(t for t in fig.data if t.name == "REPS (mean of 3 runs)")
    np.testing.assert_allclose(mean.y, runs[1]["mean_reward"])
    band = next(t for t in fig.data if t.fill == "toself")
    np.testing.assert_allclose(np.max(band.y) - np.max(mean.y), 1.0)  # std of (-1, 0, 1)
    assert any(t.name == "shaded: mean ± std over 3 runs" for t in fig.data)
    mfig = plot_learning(runs, backend="matplotlib", explore=False)
    assert isinstance(mfig, Figure)
    assert "shaded: mean ± std over 3 runs" in _legend_texts(mfig)
    assert not any("exploration" in t for t in _legend_texts(mfig))


def test_plot_learning_compares_labelled_settings():
    fig = plot_learning({"REPS": _learn_like(), "RWR": [_learn_like(), _learn_like(1.0)]})
    names = {t.name for t in fig.data}
    assert {"REPS", "RWR (mean of 2 runs)", "REPS: exploration batches"} <= names
    color = {t.name: t.marker.color for t in fig.data}
    assert color["REPS"] == color["REPS: exploration batches"] != color["RWR (mean of 2 runs)"]


@pytest.mark.parametrize(
    "runs, kwargs, match",
    [
        ({"rollouts": [0, 1]}, {}, "missing keys"),
        ({**_learn_like(), "mean_reward": [1.0]}, {}, "differ in length"),
        ([_learn_like(per=5), _learn_like(per=10)], {}, "rollout grids"),
        ([], {}, "runs"),
        ({}, {}, "empty"),
        (_learn_like(), {"backend": "bokeh"}, "backend"),
        ([3], {}, "learn\\(\\) result"),
    ],
)
def test_plot_learning_rejects_bad_input(runs, kwargs, match):
    with pytest.raises(ValueError, match=match):
        plot_learning(runs, **kwargs)


# ----------------------------------------------------------------------------- GP fits
@pytest.fixture(scope="module")
def gp_data():
    from skillkit.models.gp import ExactGP

    rng = np.random.default_rng(0)
    x = np.sort(rng.uniform(-3, 3, 12))
    y = np.sin(x) + 0.1 * rng.standard_normal(12)
    return ExactGP(additive_noise=0.0, n_steps=30).fit(x[:, None], y, rng=0), x, y


def test_plot_gp_fit_draws_mean_band_and_data(gp_data):
    gp, x, y = gp_data
    x_test = np.linspace(3, -3, 50)  # unsorted on purpose
    fig = plot_gp_fit(gp, x, y, x_test, label="SE GP", f_true=np.sin)
    mean = next(t for t in fig.data if t.name == "SE GP mean")
    m, var = gp.predict(np.sort(x_test)[:, None])
    np.testing.assert_allclose(mean.x, np.sort(x_test))
    np.testing.assert_allclose(mean.y, m)
    band = next(t for t in fig.data if t.fill == "toself")
    np.testing.assert_allclose(band.y[:50], m + 1.96 * np.sqrt(var))
    data = next(t for t in fig.data if t.name == "data")
    assert data.mode == "markers"
    np.testing.assert_allclose(data.y, y)
    assert any(t.name == "shaded: 95% band of y (mean ± 1.96 σ)" for t in fig.data)
    assert any(t.name == "true function" for t in fig.data)
    mfig = plot_gp_fit(gp, x[:, None], y, x_test, backend="matplotlib", include_noise=False)
    assert "shaded: 95% band of f (mean ± 1.96 σ)" in _legend_texts(mfig)


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        (("x2", "y", "xt"), {}, "x_train"),
        (("x", "y3", "xt"), {}, "y_train"),
        (("x", "y", "x2"), {}, "x_test"),
        (("x", "y", "one"), {}, "x_test"),
        (("x", "y", "xt"), {"backend": "svg"}, "backend"),
    ],
)
def test_plot_gp_fit_rejects_bad_input(gp_data, args, kwargs, match):
    gp, x, y = gp_data
    values = {
        "x": x,
        "y": y,
        "xt": np.linspace(-3, 3, 5),
        "x2": np.zeros((12, 2)),
        "y3": y[:3],
        "one": [0.0],
    }
    with pytest.raises(ValueError, match=match):
        plot_gp_fit(gp, *(values[a] for a in args), **kwargs)


def test_plot_gp_fit_needs_a_fitted_model(gp_data):
    from skillkit.models.gp import ExactGP

    _, x, y = gp_data
    with pytest.raises(ValueError, match="model"):
        plot_gp_fit(object(), x, y, x)
    with pytest.raises(RuntimeError, match="fit"):
        plot_gp_fit(ExactGP(), x, y, x)


# ---------------------------------------------------------------------------- packaging
def test_notebook_widgets_are_a_dev_dependency():
    """tqdm.auto draws its bars as widgets in notebooks only with ipywidgets installed."""
    tomllib = pytest.importorskip("tomllib")
    dev = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert any(r.startswith("ipywidgets") for r in dev["dev"])
    assert "- ipywidgets" in (ROOT / "environment.yml").read_text()


def test_log_bands_below_zero_are_drawn_to_the_panel_bottom():
    """A mean ± std band whose lower bound is ≤ 0 cannot be drawn on a log axis: it reaches
    down to the panel's smallest positive value instead of vanishing (plotly drops it)."""
    x = [1.0, 2.0, 3.0]
    r = _result(
        [
            Series(
                "a", x, [10.0, 100, 1e3], lower=[-5.0, 50, 500], upper=[25, 150, 1.5e3], log_y=True
            ),
            Series("b", x, [2.0, 3.0, 4.0], log_y=True),
        ]
    )
    band = next(t for t in plotly_figure(r).data if t.fill == "toself")
    assert min(band.y) == 2.0 and all(v > 0 for v in band.y)


def test_line_figure_draws_named_curves_and_rejects_bad_pairs():
    from skillkit.viz.figures import line_figure

    fig = line_figure({"a": ([0, 1, 2], [1.0, 2.0, 3.0]), "b": ([0, 1], [0.0, 1.0])}, ylabel="y")
    assert [t.name for t in fig.data] == ["a", "b"] and list(fig.data[0].y) == [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match="curves"):
        line_figure({})
    with pytest.raises(ValueError, match=r"curves\['a'\] y"):
        line_figure({"a": ([0, 1, 2], [1.0, 2.0])})


def test_prediction_figure_band_is_the_sample_percentiles():
    from skillkit.viz.figures import prediction_figure

    rng = np.random.default_rng(0)
    predicted = rng.standard_normal((2, 50, 6, 3))
    real = [rng.standard_normal((6, 3)) for _ in range(2)]
    fig = prediction_figure(predicted, real, dim=1, label="q")
    means = [t for t in fig.data if t.name == "predicted mean"]
    assert len(means) == 2
    np.testing.assert_allclose(means[1].y, predicted[1, :, :, 1].mean(0))
    reals = [t for t in fig.data if t.name == "real"]
    np.testing.assert_allclose(reals[0].y, real[0][:, 1])
    with pytest.raises(ValueError, match="real"):
        prediction_figure(predicted, real[:1])
    with pytest.raises(ValueError, match="dim"):
        prediction_figure(predicted, real, dim=3)


def test_prediction_figure_takes_one_deterministic_prediction_per_pair():
    from skillkit.viz.figures import prediction_figure

    predicted = np.arange(2 * 5 * 2, dtype=float).reshape(2, 5, 2)
    fig = prediction_figure(predicted, [np.zeros((5, 2))] * 2, dim=1)
    means = [t for t in fig.data if t.name == "predicted mean"]
    np.testing.assert_array_equal(means[0].y, predicted[0, :, 1])
    assert not any(t.fill for t in fig.data)  # no band from a single prediction


# ------------------------------------------------------------------ notebook rendering
def _axes_of(fig, prefix):
    return [fig.layout[k] for k in fig.layout if k.startswith(prefix) and fig.layout[k].domain]


def test_plotly_figures_fit_the_notebook_width_with_the_legend_below():
    """No fixed width (it would cut legends and colour bars in a notebook cell): the figure
    is responsive, its legend horizontal below the panels, axis labels given room."""
    series = [
        Series(f"curve {i}", [1, 2, 3], [i, i + 1, i + 2], panel=f"p{i % 3}").to_dict()
        for i in range(6)
    ]
    fig = plotly_figure(_result(series))
    assert fig.layout.width is None and fig.layout.autosize is True
    assert fig.layout.showlegend is True
    assert fig.layout.legend.orientation == "h" and fig.layout.legend.y < 0
    assert all(ax.automargin for ax in _axes_of(fig, "xaxis") + _axes_of(fig, "yaxis"))


def test_a_panel_with_several_series_shows_a_legend_a_single_curve_none():
    two = [Series(n, [1, 10, 100], [1, 2, 3], panel="p", log_x=True).to_dict() for n in "ab"]
    assert plotly_figure(_result(two)).layout.showlegend is True
    assert len(_legend_texts(matplotlib_figure(_result(two)))) == 2
    assert plotly_figure(_result()).layout.showlegend is False


def test_log_axes_label_ticks_as_powers_of_ten_not_si_prefixes():
    """fig4.5 showed "1µ", "1p" ticks: log axes use exponent notation."""
    s = Series("a", [1, 10, 100], [1e-30, 1e-3, 1.0], panel="p", log_x=True, log_y=True)
    fig = plotly_figure(_result([s.to_dict()]))
    assert fig.layout.xaxis.type == "log" and fig.layout.xaxis.exponentformat == "power"
    assert fig.layout.yaxis.type == "log" and fig.layout.yaxis.exponentformat == "power"


def test_a_log_x_panel_under_one_decade_is_linear_and_its_label_says_so():
    """fig4.7: rollouts 10..28 on a log axis read as a linear axis labelled "log scale"."""
    label = "real rollouts (log scale; after the first batch)"
    s = Series("a", [10, 20, 28], [1, 2, 3], panel="p", xlabel=label, log_x=True)
    fig = plotly_figure(_result([s.to_dict()]))
    assert fig.layout.xaxis.type != "log"
    assert fig.layout.xaxis.title.text == "real rollouts (after the first batch)"
    ax = matplotlib_figure(_result([s.to_dict()])).axes[0]
    assert ax.get_xscale() == "linear" and "log" not in ax.get_xlabel()
    wide = Series("a", [1, 10, 100], [1, 2, 3], panel="p", xlabel="M (log scale)", log_x=True)
    fig = plotly_figure(_result([wide.to_dict()]))
    assert fig.layout.xaxis.type == "log" and fig.layout.xaxis.title.text == "M (log scale)"


def test_axis_ranges_contain_every_point_and_band():
    """fig4.10 / fig4.12 smoke: lines drawn outside the panel. Every point and band lies
    inside the explicit axis ranges; a one-point line is drawn as a marker."""
    series = [
        Series("a", [4, 5], [0.685, 0.685], panel="p", lower=[0.6, 0.6], upper=[0.7, 0.71]),
        Series("b", [25], [0.502], panel="p"),
    ]
    fig = plotly_figure(_result([s.to_dict() for s in series]))
    (x0, x1), (y0, y1) = fig.layout.xaxis.range, fig.layout.yaxis.range
    assert x0 < 4 and x1 > 25 and y0 < 0.502 and y1 > 0.71
    single = next(t for t in fig.data if t.name == "b")
    assert "markers" in single.mode
    line = [
        ln
        for ln in matplotlib_figure(_result([s.to_dict() for s in series])).axes[0].lines
        if ln.get_label() == "b"
    ][0]
    assert line.get_marker() == "o"


def test_every_heatmap_has_a_titled_colour_bar_with_values():
    """ch5's heatmaps: each panel's colour bar shows tick labels and what it measures (a
    panel with another colour range, fig5.3's noise floor, gets its own)."""
    z = [[0.0, 1.0], [2.0, 3.0]]
    series = [
        Series("log10 e, embedding", [0, 1], [0, 1], panel="a", kind="heatmap", z=z, zmax=3),
        Series("log10 e, noise floor", [0, 1], [0, 1], panel="b", kind="heatmap", z=z, zmin=-30),
    ]
    fig = plotly_figure(_result([s.to_dict() for s in series]))
    heatmaps = [t for t in fig.data if t.type == "heatmap"]
    assert all(t.showscale and t.colorbar.showticklabels for t in heatmaps)
    assert [t.colorbar.title.text for t in heatmaps] == ["log10 e", "log10 e"]
    assert heatmaps[0].colorbar.x != heatmaps[1].colorbar.x  # beside its own panel
    labels = [
        ax.get_ylabel() for ax in matplotlib_figure(_result([s.to_dict() for s in series])).axes
    ]
    assert labels.count("log10 e") == 2


def test_a_dashed_series_is_drawn_dashed_and_on_top():
    """The DMP figure's demonstration (Series.dash) is dashed and drawn over the fit."""
    series = [
        Series("demonstration", [0, 1, 2], [0, 1, 1], panel="q", dash="dash"),
        Series("DMP fit", [0, 1, 2], [0, 1, 1], panel="q"),
    ]
    fig = plotly_figure(_result([s.to_dict() for s in series]))
    lines = [t for t in fig.data if t.type == "scatter"]
    assert lines[-1].name == "demonstration" and lines[-1].line.dash == "dash"
    assert lines[0].line.dash == "solid"
    assert lines[-1].legendrank < lines[0].legendrank  # the legend keeps the series order
    ax = matplotlib_figure(_result([s.to_dict() for s in series])).axes[0]
    demo = next(ln for ln in ax.lines if ln.get_label() == "demonstration")
    fit = next(ln for ln in ax.lines if ln.get_label() == "DMP fit")
    assert demo.get_linestyle() == "--" and fit.get_linestyle() == "-"
    assert demo.get_zorder() > fit.get_zorder()
    assert "dash" not in Series("a", [0], [0]).to_dict()  # old result.json files load as before
    with pytest.raises(ValueError, match="dash"):
        plotly_figure(_result([{**series[0].to_dict(), "dash": "wavy"}]))


def test_long_panel_titles_wrap_and_the_title_block_clears_them():
    """fig5.5's panel titles ran into each other and fig5.7's subtitle into the panel
    title: panel titles are wrapped to the column and the top margin holds every title
    line (plotly spaces each at 1.3 × 15 px)."""
    name = "(a) kernel embedding: log10 Σ_t e_x_t (Σ_t e_x_t in rad² + (rad/s)²) " * 2
    series = [Series("a", [0, 1], [0, 1], panel=f"{name}{i}").to_dict() for i in range(4)]
    summary = {"claim": "a long claim " * 60, "holds": True, "statement": "numbers " * 80}
    fig = plotly_figure(_result(series, summary=summary))
    titles = [a for a in fig.layout.annotations if a.text.startswith("(a)")]
    assert len(titles) == 4
    assert all(max(len(x) for x in t.text.split("<br>")) <= 60 for t in titles)
    n_title_lines = fig.layout.title.text.count("<br>") + 1
    n_panel_lines = titles[0].text.count("<br>") + 1
    assert fig.layout.margin.t >= 19.5 * n_title_lines + 18 * n_panel_lines
    # rows are spaced for the wrapped titles of the next row
    top_row = fig.layout.yaxis.domain[0]
    next_row = fig.layout.yaxis3.domain[1]
    plot_h = fig.layout.height - fig.layout.margin.t - fig.layout.margin.b
    assert (top_row - next_row) * plot_h >= 18 * n_panel_lines + 60
