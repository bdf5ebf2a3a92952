"""`compare_samples`, the table comparison's result in the shape of release 0.1 (read by `jaxeac study`).

The comparison itself is `jaxeac.stats.engine.compare`; this turns its rows into the old
dictionary (``diff_ci95``, ``iqm_ci95``, ``p_improvement_ci95`` at the 95 % level).
"""

from __future__ import annotations

from jaxeac.stats.engine import compare
from jaxeac.stats.inputs import from_arrays
from jaxeac.stats.tasks import prob_improvement  # noqa: F401 (offered here too)


def compare_samples(
    samples: dict,
    *,
    baseline=None,
    treatment=None,
    resamples: int = 10_000,
    alpha: float = 0.05,
    key=0,
    chunk: int = 1000,
) -> dict:
    """`compare({algo: per-seed values})` as release 0.1's dict: {"family", "comparisons_in_family",
    "alpha", "resamples", "key", "algorithms", "comparisons"} (unpaired rows)."""
    res = compare(
        from_arrays(samples),
        baseline=baseline,
        treatment=treatment,
        level=round(1 - alpha, 12),
        resamples=resamples,
        key=key,
        paired="unpaired",
        chunk=chunk,
    )
    algos = {
        a["algo"]: {"n": a["n"], "mean": a["mean"], "iqm": a["iqm"], "iqm_ci95": a["iqm_ci"]}
        for a in res.algorithms
    }
    rows = [
        {
            "x": r["x"],
            "y": r["y"],
            "n_x": r["n_x"],
            "n_y": r["n_y"],
            "mean_x": r["mean_x"],
            "mean_y": r["mean_y"],
            "diff": r["diff"],
            "diff_ci95": r["diff_ci"],
            "p_welch": r["p_welch"],
            "p_holm": r["p_holm"],
            "hedges_g": r["hedges_g"],
            "iqm_x": algos[r["x"]]["iqm"],
            "iqm_x_ci95": algos[r["x"]]["iqm_ci95"],
            "iqm_y": algos[r["y"]]["iqm"],
            "iqm_y_ci95": algos[r["y"]]["iqm_ci95"],
            "p_improvement": r["p_improvement"],
            "p_improvement_ci95": r["p_improvement_ci"],
        }
        for r in res.rows
    ]
    return {
        "family": res.family,
        "comparisons_in_family": res.family_size,
        "alpha": alpha,
        "resamples": resamples,
        "key": res.key,
        "algorithms": algos,
        "comparisons": rows,
    }
