"""The study's one figure (``fig_study.png``): a panel per task, drawn as each task's runs end.

Each algorithm's mean cumulative successes over trials, with a pointwise 95 % CI band, from the
per-trial counts of the cumulative values (`jaxeac.stats.cumulative.cumulative_counts`, [T, T + 1] per
algorithm). The panels are drawn on a thread of the figure's own, beside the later tasks' runs, so
the study's end waits only for the legend and the PNG; the layout is fixed (no tight-layout pass:
0.7 s of a 2.8 s figure of 11 panels on a 2-core CPU). Given a `jaxeac.running.helper.Helper` (a
study on a GPU), the figure's thread computes each panel's lines (means and CI bands, [T] per
algorithm) and the helper process draws them, so that drawing never holds this process's
interpreter lock beside the statistics; if the helper has gone, the figure is drawn here instead.
"""

from __future__ import annotations

import io
import itertools
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

STUDY_FIGURE = "fig_study.png"

#: Inches around and between the panels (fixed, so no layout pass is needed).
_LEFT, _RIGHT, _TOP, _LABEL, _LEGEND = 0.62, 0.12, 0.28, 0.42, 0.62


class StudyFigure:
    """`STUDY_FIGURE` of `tasks` (in order) at `n` seeds per algorithm: `add` draws a task's panel
    as its counts come in, `finish` finishes the figure (legend, PNG bytes) once every panel is
    drawn. A `matplotlib.figure.Figure` of its own (no pyplot state), used by one thread only;
    `timed(work)` wraps each piece of work on this process's side (e.g. a timeline's phase);
    `helper`: a `Helper` that draws instead (module docstring)."""

    def __init__(self, tasks: Sequence[str], n: int, timed: Callable[[Callable], object] | None = None,
                 helper=None) -> None:
        self._tasks, self._n, self._helper = list(tasks), n, helper
        self._timed = timed or (lambda work: work())
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="jaxeac-study-figure")
        self._lines: dict[str, dict] = {}  # each task's lines, kept while a helper draws them
        self._id = f"{os.getpid()}-{next(_IDS)}"
        self._axes: Future | None = None if helper else self._pool.submit(self._timed, self._start)
        self._drawn: list[Future] = []

    def add(self, task: str, counts: dict[str, np.ndarray]) -> None:
        """Draw `task`'s panel: `counts[algo]`, int [T, T + 1] (`cumulative_counts`)."""
        self._drawn.append(self._pool.submit(self._timed, lambda: self._add(task, counts)))

    def finish(self) -> Future:
        """Finish the figure once its panels are drawn: a future of its PNG bytes (raising what
        drawing raised)."""
        if self._helper is None:
            return self._pool.submit(self._timed, self._finish)
        return self._pool.submit(self._timed, self._finish_in_helper)

    def close(self, drop: bool = False) -> None:
        """End the figure's thread once its work is done (`drop`: the work still queued is dropped)."""
        self._pool.shutdown(wait=False, cancel_futures=drop)

    def __enter__(self) -> StudyFigure:
        return self

    def __exit__(self, kind, *exc) -> None:
        self.close(drop=kind is not None)  # a study that stops draws no more

    def _add(self, task: str, counts: dict[str, np.ndarray]):
        lines = panel_lines(counts)
        if self._helper is None:
            return self._panel(task, lines)
        from jaxeac.running.helper import HelperError

        self._lines[task] = lines
        try:
            return self._submit(_draw_panel, self._id, self._tasks, self._n, task, lines)
        except HelperError:  # gone: `finish` draws here
            return None

    def _finish_in_helper(self) -> bytes:
        from jaxeac.running.helper import HelperError

        sent = [drawn.result() for drawn in self._drawn]  # raises what a panel's lines raised
        try:
            if all(s is not None for s in sent):
                for s in sent:
                    s.result()
                return self._submit(_draw_finish, self._id, self._tasks, self._n).result()
        except HelperError:
            pass
        self._start()  # the helper has gone: the figure is drawn here
        for task, lines in self._lines.items():
            self._panel(task, lines)
        return self._png()

    def _submit(self, fn, *args):
        """`fn(*args)` in the helper: on its figure lane where it has one (`FIGURE_LANE`), so that
        E8's jobs never hold it up; else with its other jobs."""
        if FIGURE_LANE in self._helper.lanes:
            return self._helper.submit_to(FIGURE_LANE, fn, *args)
        return self._helper.submit(fn, *args)

    def _start(self):
        from matplotlib.figure import Figure

        cols = min(4, len(self._tasks))
        rows = -(-len(self._tasks) // cols)
        width, height = 3.6 * cols, 2.9 * rows
        fig = Figure(figsize=(width, height))
        bottom = _LABEL + _LEGEND
        axes = fig.subplots(rows, cols, squeeze=False, gridspec_kw={
            "left": _LEFT / width, "right": 1 - _RIGHT / width, "top": 1 - _TOP / height,
            "bottom": bottom / height, "wspace": 0.28, "hspace": 0.42})
        for i, ax in enumerate(axes.flat):
            if i >= len(self._tasks):
                ax.axis("off")
            elif i + cols >= len(self._tasks):  # the lowest panel of its column
                ax.set_xlabel("trial", fontsize=8)
        for ax in axes[:, 0]:
            ax.set_ylabel("successes so far", fontsize=8)
        self._fig, self._by_task = fig, dict(zip(self._tasks, axes.flat, strict=False))

    def _panel(self, task: str, lines: dict) -> None:
        from jaxeac import style

        ax = self._by_task[task]
        for algo, (mean, half) in lines.items():
            trials = np.arange(1, mean.size + 1)
            ax.plot(trials, mean, color=style.color(algo), lw=1.4, label=style.label(algo))
            if half is not None:
                ax.fill_between(trials, mean - half, mean + half, color=style.color(algo), alpha=0.25, lw=0)
        ax.set_title(task, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)

    def _finish(self) -> bytes:
        for drawn in [self._axes, *self._drawn]:  # done (one thread, in order): raises what a panel raised
            drawn.result()
        return self._png()

    def _png(self) -> bytes:
        handles, labels = self._by_task[self._tasks[0]].get_legend_handles_labels()
        self._fig.legend(handles, labels, loc="lower center", ncol=min(8, max(1, len(labels))), fontsize=7,
                         title=f"mean cumulative successes of {self._n:,} seeds per algorithm "
                               "(shaded: 95% CI of the mean)",
                         title_fontsize=7, bbox_to_anchor=(0.5, 0.0))
        png = io.BytesIO()
        self._fig.savefig(png, dpi=110)
        return png.getvalue()


def panel_lines(counts: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """{algo: (mean cumulative successes per trial [T], the half-width of its 95 % CI [T], or None
    for one seed)} from `counts[algo]`, int [T, T + 1] (`cumulative_counts`)."""
    from jaxeac.stats.cumulative import cumulative_lines

    lines = {algo: cumulative_lines(c) for algo, c in counts.items()}
    return {algo: (line["mean"], line["half"]) for algo, line in lines.items()}


#: The helper's lane (`jaxeac.running.helper.Helper.submit_to`) the figure is drawn on, apart from
#: E8's jobs: queued behind them, a study's figure was ready 0.7-1.0 s after its statistics.
FIGURE_LANE = "figure"

_IDS = itertools.count()
#: In a helper process: the figures it draws, by id (`_draw_panel`, `_draw_finish`).
_FIGURES: dict[str, StudyFigure] = {}
_FIGURES_LOCK = threading.Lock()


def _figure(fid: str, tasks, n: int) -> StudyFigure:
    with _FIGURES_LOCK:
        if fid not in _FIGURES:
            _FIGURES[fid] = StudyFigure(tasks, n)
        return _FIGURES[fid]


def _draw_panel(fid: str, tasks, n: int, task: str, lines: dict) -> None:
    """(In a helper.) Draw `task`'s panel of figure `fid`, on that figure's own thread."""
    figure = _figure(fid, tasks, n)
    figure._pool.submit(figure._panel, task, lines).result()


def _draw_finish(fid: str, tasks, n: int) -> bytes:
    """(In a helper, once every panel's `_draw_panel` has returned.) Figure `fid`'s PNG; the figure
    is then let go."""
    figure = _figure(fid, tasks, n)
    with _FIGURES_LOCK:
        del _FIGURES[fid]
    try:
        return figure._pool.submit(figure._finish).result()
    finally:
        figure.close()
