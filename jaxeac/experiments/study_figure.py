"""The study's one figure (``fig_study.png``): a panel per task, drawn as each task's runs end.

Each algorithm's mean cumulative successes over trials, with a pointwise 95 % CI band, from the
per-trial counts of the cumulative values (`jaxeac.plots.cumulative_counts`, [T, T + 1] per
algorithm). The panels are drawn on a thread of the figure's own, beside the later tasks' runs, so
the study's end waits only for the legend and the PNG; the layout is fixed (no tight-layout pass:
0.7 s of a 2.8 s figure of 11 panels on a 2-core CPU).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

STUDY_FIGURE = "fig_study.png"

#: Inches around and between the panels (fixed, so no layout pass is needed).
_LEFT, _RIGHT, _TOP, _LABEL, _LEGEND = 0.62, 0.12, 0.28, 0.42, 0.62


class StudyFigure:
    """`STUDY_FIGURE` of `tasks` (in order) at `n` seeds per algorithm: `add` draws a task's panel
    as its counts come in, `png` finishes the figure (legend, PNG bytes) once every panel is
    drawn. A `matplotlib.figure.Figure` of its own (no pyplot state), used by one thread only;
    `timed(work)` wraps each piece of drawing (e.g. a timeline's phase)."""

    def __init__(self, tasks: Sequence[str], n: int, timed: Callable[[Callable], object] | None = None) -> None:
        self._tasks, self._n = list(tasks), n
        self._timed = timed or (lambda work: work())
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="jaxeac-study-figure")
        self._axes: Future = self._pool.submit(self._timed, self._start)
        self._drawn: list[Future] = []

    def add(self, task: str, counts: dict[str, np.ndarray]) -> None:
        """Draw `task`'s panel: `counts[algo]`, int [T, T + 1] (`cumulative_counts`)."""
        self._drawn.append(self._pool.submit(self._timed, lambda: self._panel(task, counts)))

    def finish(self) -> Future:
        """Finish the figure once its panels are drawn: a future of its PNG bytes (raising what
        drawing raised)."""
        return self._pool.submit(self._timed, self._finish)

    def close(self, drop: bool = False) -> None:
        """End the figure's thread once its work is done (`drop`: the work still queued is dropped)."""
        self._pool.shutdown(wait=False, cancel_futures=drop)

    def __enter__(self) -> StudyFigure:
        return self

    def __exit__(self, kind, *exc) -> None:
        self.close(drop=kind is not None)  # a study that stops draws no more

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

    def _panel(self, task: str, counts: dict[str, np.ndarray]) -> None:
        from scipy import special

        from jaxeac import style

        ax, n = self._by_task[task], self._n
        for algo, c in counts.items():
            t = c.shape[0]
            values, trials = np.arange(t + 1), np.arange(1, t + 1)
            mean = c @ values / n
            ax.plot(trials, mean, color=style.color(algo), lw=1.4, label=style.label(algo))
            if n > 1:
                sd = np.sqrt((c * (values[None, :] - mean[:, None]) ** 2).sum(axis=1) / (n - 1))
                half = special.stdtrit(n - 1, 0.975) * sd / np.sqrt(n)
                ax.fill_between(trials, mean - half, mean + half, color=style.color(algo), alpha=0.25, lw=0)
        ax.set_title(task, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)

    def _finish(self) -> bytes:
        for drawn in [self._axes, *self._drawn]:  # done (one thread, in order): raises what a panel raised
            drawn.result()
        handles, labels = self._by_task[self._tasks[0]].get_legend_handles_labels()
        self._fig.legend(handles, labels, loc="lower center", ncol=min(8, max(1, len(labels))), fontsize=7,
                         title=f"mean cumulative successes of {self._n:,} seeds per algorithm "
                               "(shaded: 95% CI of the mean)",
                         title_fontsize=7, bbox_to_anchor=(0.5, 0.0))
        png = io.BytesIO()
        self._fig.savefig(png, dpi=110)
        return png.getvalue()

