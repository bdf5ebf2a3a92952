"""`jaxeac reproduce`: both of the paper's experiments at scale, with figures and a written verdict.

Debnath & Nassour (2014) ran each method once (n = 1). This package re-runs the grid
world (§V-A) and the bowling task (§V-B) over thousands of seeds, redraws Fig. 2,
Fig. 3, Table I and Fig. 5 from those runs, sweeps the settings the paper leaves open
(calibration), ablates the parts of EAC, and writes ``report.md``: the paper's claims
one by one, what the runs show (N, estimate, 95 % CI, Hedges' g, A12, p) and a plain
verdict decided by fixed rules (`VERDICT_RULES`).

- `runs`: the four steps, their folders and markers, and `reproduce`, which runs them;
- `measures`: the per-seed measures the steps compute;
- `claims`: the paper's claims (GRID-1…5, BOWL-1…4) and the verdict rules;
- `report`: report.md's prose, and `export_document` for docs/REPLICATION.md.

All statistics come from `jaxeac.stats` (BCa intervals, Welch and permutation tests,
Hedges' g, A12, Holm, sup-t curve bands); nothing here re-derives them.
"""

from jaxeac.experiments.reproduce.claims import ALPHA, VERDICT_RULES, judge_claims, supported
from jaxeac.experiments.reproduce.measures import (
    chance_split,
    contrast,
    greedy_reach,
    mean_ci,
    paper_position,
    path_ratios,
    path_window,
    rate_change,
    sub_key,
)
from jaxeac.experiments.reproduce.report import export_document, render_report
from jaxeac.experiments.reproduce.runs import (
    ANGLE_LATE_FROM,
    CALIBRATION_SETS,
    CALIBRATION_TOLERANCE,
    FULL,
    LATE_TRIALS,
    QUICK,
    STEPS,
    Sizes,
    reproduce,
    step_ablations,
    step_bowling,
    step_calibration,
    step_grid,
)

__all__ = [
    "ALPHA", "ANGLE_LATE_FROM", "CALIBRATION_SETS", "CALIBRATION_TOLERANCE", "FULL", "LATE_TRIALS", "QUICK",
    "STEPS", "VERDICT_RULES", "Sizes", "chance_split", "contrast", "export_document", "greedy_reach",
    "judge_claims", "mean_ci", "paper_position", "path_ratios", "path_window", "rate_change", "render_report",
    "reproduce", "step_ablations", "step_bowling", "step_calibration", "step_grid", "sub_key", "supported",
]
