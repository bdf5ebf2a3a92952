"""The numbers Debnath & Nassour (2014) publish, in one place.

The paper runs each method once (n = 1). Figures, reports and verdicts quote these
constants; no other module spells them out.
"""

from __future__ import annotations

#: §V-A, Fig. 3: trials of one grid-world run.
GRID_TRIALS = 200
#: Fig. 3: trials (of `GRID_TRIALS`) in which the single run of each method reached the goal.
GRID_SUCCESSES = {"ac": 56, "eac": 163}
#: Fig. 3: the trial after which AC's cumulative curve speeds up (read off the figure, "~180").
GRID_AC_SPEEDUP_TRIAL = 180

#: §V-B, Table I: trials of one bowling run, each of 2 chances at 10 pins.
BOWLING_TRIALS = 10
#: Most pins one bowling run can knock: 10 pins per trial.
BOWLING_MAX_PINS = 10 * BOWLING_TRIALS
#: Table I as extracted from the paper's text: (chance 1, chance 2) pins per trial.
TABLE_ONE = {
    "eac": ((3, 5), (5, 3), (2, 4), (0, 6), (3, 5), (7, 2), (5, 4), (5, 3), (4, 5), (6, 4)),
    "ac": ((5, 2), (2, 4), (4, 4), (3, 2), (4, 5), (7, 0), (6, 1), (3, 0), (1, 6), (5, 3)),
}
#: Table I totals, pins of `BOWLING_MAX_PINS` (AC 67, EAC 81).
BOWLING_PINS = {a: sum(c1 + c2 for c1, c2 in TABLE_ONE[a]) for a in ("ac", "eac")}
#: Fig. 5: EAC's shoulder angles settle "after about 5 trials".
ANGLE_SETTLE_TRIALS = 5
