"""Every figure type, drawn from small data and read back from Matplotlib's artist tree: each
algorithm in its palette colour (jaxeac/style.py), a legend entry for every mark, labelled axes
and colour bars, and colour scales that fit the data (sequential when one-signed)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.colors import to_hex  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

import jaxeac  # noqa: E402
from jaxeac import plots, style  # noqa: E402
from jaxeac.stats.cumulative import cumulative_counts, cumulative_lines  # noqa: E402

ALGOS = list(style.PALETTE)


@pytest.fixture
def drawn(monkeypatch):
    """The figures saved while the test runs, still whole after the function closes them."""
    figures: list[Figure] = []
    save = Figure.savefig

    def keep(self, *args, **kwargs):
        figures.append(self)
        return save(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return figures


def legend_texts(fig: Figure) -> list[str]:
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]
    return [t.get_text() for leg in legends for t in leg.get_texts()]


def legend_handles(fig: Figure) -> dict[str, object]:
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]
    return {t.get_text(): h for leg in legends
            for t, h in zip(leg.get_texts(), leg.legend_handles, strict=True)}


def plot_axes(fig: Figure) -> list:
    """The axes that hold data (colour bars aside)."""
    return [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]


def colorbars(fig: Figure) -> list:
    return [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]


def assert_labelled(fig: Figure):
    for ax in plot_axes(fig):  # an axis shared with a labelled one is labelled there
        xs, ys = ax.get_shared_x_axes().get_siblings(ax), ax.get_shared_y_axes().get_siblings(ax)
        assert any(a.get_xlabel().strip() for a in xs), f"axes {ax.get_title()!r} has no x label"
        assert any(a.get_ylabel().strip() for a in ys), f"axes {ax.get_title()!r} has no y label"
    for cb in colorbars(fig):
        assert cb.get_ylabel().strip() or cb.get_xlabel().strip(), "a colour bar without a label"


def color_of(handle) -> str:
    get = getattr(handle, "get_color", None) or handle.get_facecolor
    c = get()
    return to_hex(c[0] if np.ndim(c) == 2 else c)


def test_palette_is_one_distinct_colour_per_algorithm():
    from jaxeac.algorithm.config import ALGORITHMS, BASELINES

    assert set(style.PALETTE) == set(ALGORITHMS) | set(BASELINES)
    assert len(set(style.PALETTE.values())) == len(style.PALETTE)
    assert style.color("eac") == style.VERMILLION and style.color("ac") == style.BLUE


def test_scales_diverge_only_for_differences_of_both_signs():
    assert style.scale([3, 150], difference=True) == {"cmap": style.SEQUENTIAL, "vmin": 0.0, "vmax": 150.0}
    assert style.scale([-3, 150], difference=True) == {"cmap": style.DIVERGING, "vmin": -150.0, "vmax": 150.0}
    assert style.scale([-3, 150], difference=False)["cmap"] == style.SEQUENTIAL
    assert style.text_color((0.1, 0.0, 0.0, 1)) == "white" and style.text_color((1, 1, 0.8, 1)) == "black"


def test_cumulative_figure_colours_every_algorithm_and_keys_the_spread(drawn, tmp_path):
    rng = np.random.default_rng(0)
    lines = {a: cumulative_lines(cumulative_counts(rng.random((20, 30)) < 0.3), spread=True) for a in ALGOS}
    plots.cumulative_success_figure(lines, tmp_path / "f.png")
    (fig,) = drawn
    handles = legend_handles(fig)
    for algo in ALGOS:
        assert color_of(handles[f"{style.label(algo)}: mean of 20 seeds"]) == style.color(algo).lower()
    assert {"shaded: 95% CI of the mean", "dotted: 5% and 95% of seeds"} <= set(handles)
    assert handles["dotted: 5% and 95% of seeds"].get_linestyle() == ":"
    assert_labelled(fig)


def test_policy_figure_keys_goal_obstacles_start_and_paths(drawn, tmp_path):
    env = jaxeac.make("grid-paper-v0")
    g = env.map
    policy = np.zeros(g.height * g.width, int)  # "up" everywhere: from the top-left start, 1 move
    plots.policy_figure(g, {"ac": policy, "eac": policy}, tmp_path / "f.png", seed=0, max_steps=20)
    (fig,) = drawn
    texts = legend_texts(fig)
    assert {"obstacle", "goal", "start", "greedy action in each cell"} <= set(texts)
    handles = legend_handles(fig)
    for algo in ("ac", "eac"):
        path = handles[f"{style.label(algo)}'s greedy path from the start"]
        assert color_of(path) == style.color(algo).lower()
    titles = [ax.get_title() for ax in plot_axes(fig)]
    assert all("moves)" in t or "move)" in t for t in titles)
    assert not any("(1 moves)" in t for t in titles)
    assert_labelled(fig)


def test_angle_figure_keeps_the_first_seed_visible_under_the_second(drawn, tmp_path):
    theta = np.random.default_rng(1).choice([-0.1, 0.0, 0.1], (8, 10, 2))
    plots.angle_figure({"ac": theta, "eac": theta.copy()}, tmp_path / "f.png")  # identical seed 0
    (fig,) = drawn
    handles = legend_handles(fig)
    for algo in ("ac", "eac"):
        name = style.label(algo)
        assert {f"{name}: mean over seeds", f"{name}: 5–95% of seeds", f"{name}: seed 0"} <= set(handles)
        assert color_of(handles[f"{name}: mean over seeds"]) == style.color(algo).lower()
    ax = plot_axes(fig)[0]
    seed_lines = {line.get_label(): line for line in ax.get_lines() if line.get_label().endswith("seed 0")}
    ac, eac = seed_lines["AC: seed 0"], seed_lines["EAC: seed 0"]
    assert ac.get_markersize() > eac.get_markersize() and ac.get_markerfacecolor() == "none"
    assert_labelled(fig)


def _sweep_rows(diffs):
    rows = []
    for (a, b), d in zip([(x, y) for x in (0.05, 0.1) for y in (0.1, 0.3)], diffs, strict=True):
        for algo in ("ac", "eac", "q_learning"):
            row = {"alpha": a, "beta": b, "algo": algo, "mean_successes": 20.0 + d * (algo == "eac"),
                   "ci95_lo": 18.0, "ci95_hi": 22.0 + d * (algo == "eac")}
            if algo != "q_learning":
                row["eac_minus_ac"] = d
            rows.append(row)
    return rows


@pytest.mark.parametrize("diffs, cmap", [((5.0, 80.0, 140.0, 150.0), style.SEQUENTIAL),
                                         ((-20.0, 3.0, 60.0, 90.0), style.DIVERGING)])
def test_sweep_heatmap_scale_labels_and_readable_text(drawn, tmp_path, diffs, cmap):
    plots.sweep_heatmap(_sweep_rows(diffs), "alpha", "beta", tmp_path / "f.png")
    (fig,) = drawn
    (ax,) = plot_axes(fig)
    (im,) = ax.get_images()
    assert im.get_cmap().name == cmap
    if cmap == style.DIVERGING:
        assert im.norm.vmin == -im.norm.vmax
    else:
        assert im.norm.vmin == 0
    assert_labelled(fig)
    for text in ax.texts:  # every cell's number contrasts with its cell
        x, y = text.get_position()
        cell = im.cmap(im.norm(im.get_array()[int(y), int(x)]))
        assert text.get_color() == style.text_color(cell)


def test_sweep_lines_one_key(drawn, tmp_path):
    plots.sweep_lines(_sweep_rows((1.0, 2.0, 3.0, 4.0)), "alpha", tmp_path / "f.png")
    (fig,) = drawn
    handles = legend_handles(fig)
    assert set(handles) == {"AC", "EAC", "q_learning"}
    bars = {c.get_label(): c for c in plot_axes(fig)[0].containers}  # the errorbar containers
    for algo in ("ac", "eac", "q_learning"):
        assert to_hex(bars[style.label(algo)].lines[0].get_color()) == style.color(algo).lower()
    assert_labelled(fig)


def test_calibration_landscape_all_positive_is_sequential_from_zero(drawn, tmp_path):
    points = [{"preset": p, "chances": c, "alpha": a, "beta": b, "ac": 50.0, "eac": 180.0, "diff": 100.0 + a}
              for p in ("paper", "paper9") for c in (20, 40) for a in (0.05, 0.1) for b in (0.1, 0.9)]
    plots.calibration_landscape(points, tmp_path / "f.png")
    (fig,) = drawn
    images = [im for ax in plot_axes(fig) for im in ax.get_images()]
    assert {im.get_cmap().name for im in images} == {style.SEQUENTIAL}
    assert {im.norm.vmin for im in images} == {0.0}
    (cb,) = colorbars(fig)
    assert "EAC − AC" in cb.get_ylabel()


def test_band_path_ratio_and_forest_figures(drawn, tmp_path):
    t = 12
    mean = np.linspace(0, 5, t)
    curves = {a: {"mean": mean, "band": (mean - 1, mean + 1), "spread": (mean - 2, mean + 2), "n": 10}
              for a in ("ac", "eac")}
    plots.cumulative_band_figure(curves, tmp_path / "a.png", paper={"ac": 3, "eac": 5})
    ratio = {"mean": np.full(t, 1.5), "lo": np.ones(t), "hi": np.full(t, 2.0)}
    share = {"mean": np.full(t, 0.5), "lo": np.zeros(t), "hi": np.ones(t)}
    plots.path_ratio_figure({a: {"ratio": ratio, "optimal": share, "n": 10} for a in ("ac", "eac")},
                            tmp_path / "b.png", window=(3, 6))
    rows = [{"label": a, "algo": a, "diff": 1.0, "ci": (0.0, 2.0)} for a in ("eac", "eac_success_only")]
    plots.forest_figure(rows, tmp_path / "c.png", title="variants", xlabel="minus AC")
    band, ratio_fig, forest = drawn
    for fig in drawn:
        assert_labelled(fig)
    hb = legend_handles(band)
    assert color_of(hb["EAC: mean of 10 seeds"]) == style.color("eac").lower()
    assert "EAC: 5% and 95% of seeds (dotted)" in hb and "paper's single AC run: 3" in hb
    hr = legend_handles(ratio_fig)
    assert {"AC: pointwise 95% CI", "EAC: mean of 10 seeds", "trials 3-6 (compared)"} <= set(hr)
    hf = legend_handles(forest)
    assert color_of(hf["eac_success_only − AC"]) == style.color("eac_success_only").lower()
    assert {"95% CI", "no difference"} <= set(hf)


def test_run_folder_and_comparison_figures(drawn, tmp_path):
    """A real run folder: Fig. 2, Fig. 3 and the three compare_*.png of `jaxeac compare`."""
    out = tmp_path / "run"
    jaxeac.run("grid-paper-v0", ["ac", "eac"], seeds=24, out=out)
    jaxeac.compare(out, resamples=400)
    names = {fig.get_suptitle() or plot_axes(fig)[0].get_title(): fig for fig in drawn}
    assert len(drawn) >= 5
    for fig in drawn:
        assert_labelled(fig)
    curves = next(f for title, f in names.items() if "simultaneous" in title)
    handles = legend_handles(curves)
    assert color_of(handles["EAC: mean of 24 seeds"]) == style.color("eac").lower()
    assert color_of(handles["AC: mean of 24 seeds"]) == style.color("ac").lower()
    assert {"EAC: band", "AC: band", "EAC − AC", "band of the difference"} <= set(handles)
    ecdf = names["Per-seed distributions (ECDF)"]
    assert {to_hex(line.get_color()) for ax in plot_axes(ecdf) for line in ax.get_lines()} == \
        {style.color("ac").lower(), style.color("eac").lower()}


def test_the_distributions_figure_drawn_before_the_statistics_is_the_one_drawn_after(tmp_path):
    """`compare_experiment` hands `on_counts` the figures' data it returns, as soon as the per-seed
    measures exist; the distributions drawn from it alone (`jaxeac.plots.comparison_png`, as
    `jaxeac grid` does in its figure helper while the statistics run) are the PNG
    `comparison_figures` writes from the finished statistics, byte for byte; the others need those."""
    from jaxeac.stats.report import FIGURES
    from jaxeac.stats.run import compare_experiment

    rng = np.random.default_rng(3)
    sb, st = rng.random((60, 12)) < 0.3, rng.random((60, 12)) < 0.6
    early = []
    stats, plot = compare_experiment(sb, st, resamples=200, calibration_splits=4, paired=True,
                                     on_counts=lambda sides, data: early.append((sides, data)))
    [(sides, data)] = early
    assert sides == {"baseline": "ac", "treatment": "eac"} and data is plot
    plots.comparison_figures(stats, plot, tmp_path, FIGURES)
    assert plots.comparison_png("distributions", sides, data) == (tmp_path / FIGURES["distributions"]).read_bytes()
    assert plots.comparison_png("improvement", stats, plot) == (tmp_path / FIGURES["improvement"]).read_bytes()
    assert plots.comparison_png("curves", sides, data) == b""  # no curves without the statistics
