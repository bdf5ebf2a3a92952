"""Make tests/data/rliable_reference.json: rliable's own numbers on a fixed dataset.

rliable (Agarwal et al. 2021) is the reference for the aggregates across tasks, but it does
not install beside this project (it needs pandas < 3 and arch 7), so its numbers were made
once, in a separate environment, by this script, and `tests/test_engine.py` pins them::

    python3 -m venv /tmp/rl && /tmp/rl/bin/pip install rliable "pandas<3"
    /tmp/rl/bin/python tests/data/make_rliable_reference.py    # writes the JSON beside it

(made with rliable 1.2.0, arch 7.2.0, pandas 2.3.3, numpy 2.4.6, scipy 1.17.1; the versions
are recorded in the output too). The script uses only NumPy and rliable. The dataset: 3
algorithms × 4 tasks × 12 runs of raw scores on scales 100× apart, drawn from a fixed NumPy
generator and written into the JSON rounded to 4 decimals (the test reads them back), with
min–max reference scores per task. rliable gets the min–max normalised [runs, tasks] matrices
and gives the point estimates of `metrics.aggregate_mean`, `aggregate_median`,
`aggregate_iqm`, `aggregate_optimality_gap` (γ = 1) and `probability_of_improvement`, with
95 % percentile intervals of `library.get_interval_estimates` (its stratified bootstrap,
`REPS` resamples), and the performance profile of `library.create_performance_profile` at
the thresholds `TAU`.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ALGOS = ("A", "B", "C")
TASKS = ("t0", "t1", "t2", "t3")
RUNS = 12
REFERENCE = {"t0": (0.0, 1.0), "t1": (0.0, 100.0), "t2": (-10.0, 10.0), "t3": (5.0, 505.0)}
REPS = 50_000
TAU = [0.0, 0.25, 0.5, 0.75, 1.0]


def dataset() -> dict:
    """{task: {algo: [runs]}} raw scores, rounded to 4 decimals."""
    rng = np.random.default_rng(2021)
    out = {}
    for t in TASKS:
        low, high = REFERENCE[t]
        out[t] = {}
        for j, a in enumerate(ALGOS):
            centre = 0.35 + 0.12 * j + 0.05 * rng.standard_normal()
            x = low + (high - low) * rng.normal(centre, 0.2, RUNS)
            out[t][a] = [round(float(v), 4) for v in x]
    return out


def main() -> None:
    import arch
    import pandas
    import rliable
    import scipy
    from rliable import library as rly
    from rliable import metrics

    raw = dataset()
    norm = {
        a: np.stack(
            [(np.asarray(raw[t][a]) - REFERENCE[t][0]) / (REFERENCE[t][1] - REFERENCE[t][0]) for t in TASKS], 1
        )
        for a in ALGOS
    }
    aggregates = {
        "mean": metrics.aggregate_mean,
        "median": metrics.aggregate_median,
        "iqm": metrics.aggregate_iqm,
        "optimality_gap": metrics.aggregate_optimality_gap,
    }

    def all_four(x):
        return np.array([f(x) for f in aggregates.values()])

    points, cis = rly.get_interval_estimates(norm, all_four, reps=REPS, random_state=np.random.RandomState(0))
    algos = {
        a: {k: {"estimate": float(points[a][i]), "ci": [float(v) for v in cis[a][:, i]]}
            for i, k in enumerate(aggregates)}
        for a in ALGOS
    }
    pairs_in = {f"{x},{y}": (norm[x], norm[y]) for x, y in (("B", "A"), ("C", "A"))}
    p_points, p_cis = rly.get_interval_estimates(
        pairs_in, metrics.probability_of_improvement, reps=REPS // 5, random_state=np.random.RandomState(1)
    )
    pairs = [
        {"x": k.split(",")[0], "y": k.split(",")[1], "estimate": float(np.squeeze(p_points[k])),
         "ci": [float(v) for v in np.ravel(p_cis[k])]}
        for k in pairs_in
    ]
    profiles, profile_cis = rly.create_performance_profile(norm, np.array(TAU), reps=REPS // 5)
    out = {
        "made_by": "tests/data/make_rliable_reference.py",
        "versions": {"rliable": getattr(rliable, "__version__", "1.2.0"), "arch": arch.__version__,
                     "pandas": pandas.__version__, "numpy": np.__version__, "scipy": scipy.__version__,
                     "python": sys.version.split()[0]},
        "reps": REPS,
        "level": 0.95,
        "reference": {t: list(v) for t, v in REFERENCE.items()},
        "scores": raw,
        "tau": TAU,
        "algorithms": algos,
        "pairs": pairs,
        "profiles": {a: {"share": [float(v) for v in profiles[a]],
                         "low": [float(v) for v in profile_cis[a][0]],
                         "high": [float(v) for v in profile_cis[a][1]]} for a in ALGOS},
    }
    path = Path(__file__).with_name("rliable_reference.json")
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
