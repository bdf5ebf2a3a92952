"""Statistics for AC-versus-EAC comparisons (SPEC §6).

Entry points: `jaxeac.stats.engine.compare(data, ...)` (`jaxeac.compare`) for per-seed results
from anywhere, across tasks; for a run folder it calls `compare_run_dir(run_dir, ...)`, which
writes stats.json, report.md and figures. Array-level functions (per-seed values as 1-D arrays,
curves as [seeds, trials]) are exported for notebooks; every resampling function takes an
explicit `key` (an int seed or a `jax.random` key). Which resampling path each piece takes
(raw draws, exact counts per value, or an asymptotic form above
`jaxeac.stats.large.LARGE_N` seeds) is the one rule `jaxeac.stats.large.resampling_path`.
"""

from jaxeac.rundir import load_run_dir
from jaxeac.stats.bca import bca_interval
from jaxeac.stats.calibration import calibrate
from jaxeac.stats.closed_form import (
    Estimate,
    TestResult,
    a12,
    brunner_munzel,
    hedges_g,
    holm,
    iqm,
    power_ttest,
    seeds_for_power,
    welch_t,
)
from jaxeac.stats.compare import compare_measures, permutation_test
from jaxeac.stats.curves import curve_bands
from jaxeac.stats.events import logrank, newcombe_diff, risk_ratio_ci, wilson_ci
from jaxeac.stats.groups import bca_ci, iqm_ci
from jaxeac.stats.measures import per_seed_measures
from jaxeac.stats.run import compare_experiment, compare_run_dir

__all__ = [
    "Estimate",
    "TestResult",
    "a12",
    "bca_ci",
    "bca_interval",
    "brunner_munzel",
    "calibrate",
    "compare_experiment",
    "compare_measures",
    "compare_run_dir",
    "curve_bands",
    "hedges_g",
    "holm",
    "iqm",
    "iqm_ci",
    "load_run_dir",
    "logrank",
    "newcombe_diff",
    "per_seed_measures",
    "permutation_test",
    "power_ttest",
    "risk_ratio_ci",
    "seeds_for_power",
    "welch_t",
    "wilson_ci",
]
