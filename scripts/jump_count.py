"""How many loop iterations memory jumps leave per trial: counted on the literal reference.

Runs Algorithm 1 seed by seed with the test suite's plain-Python reference
(`tests/reference.py`, paper preset) and splits each trial's chances into those taken
before it stands on a remembered state (softmax steps, needing an iteration each),
walks over remembered states whose path length is not known yet, and the jump itself
(`jaxeac.running.loops.flat_slot`). Also counts two schedules that were considered and
dropped: the jump folded into the step that reaches its state, and jumps only where a
trial starts.

    python scripts/jump_count.py --seeds 40
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=40)
    args = p.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import jax
    from reference import reference_run

    from jaxeac.algorithm.config import algorithm
    from jaxeac.envs.grid import get_map
    from jaxeac.experiments.presets import make

    preset, grid = make("paper"), get_map("paper")
    n = {"trials": 0, "chances": 0, "before": 0, "walks": 0, "jumps": 0, "iterations": 0, "folded": 0,
         "start_only": 0}
    for i in range(args.seeds):
        run = reference_run(grid, algorithm("eac"), trials=preset.trials, chances=preset.chances,
                            alpha=preset.alpha, beta=preset.beta, gamma=preset.gamma, tau=preset.temperature,
                            key=jax.random.fold_in(jax.random.key(0), i))
        remembered, known = set(), set()  # states with a success action; ... whose path length is known
        for trial in run.trials:
            length = len(trial.states)
            first = next((c for c, s in enumerate(trial.states) if s in remembered), length)
            at = next((c for c in range(first, length) if trial.states[c] in known), None)
            n["trials"] += 1
            n["chances"] += length
            n["before"] += first
            n["walks"] += (length if at is None else at) - first
            n["jumps"] += at is not None
            n["iterations"] += length if at is None else at + 1
            n["folded"] += length if at is None else max(at, 1)
            n["start_only"] += 1 if at == 0 else length
            if trial.success:
                known.update(trial.states[first:length if at is None else at])
                remembered.update(trial.states)
    t = n["trials"]
    print(f"{args.seeds} seeds x {preset.trials} trials, per trial: {n['chances'] / t:.2f} chances, "
          f"{n['before'] / t:.2f} before a remembered state, {n['walks'] / t:.2f} walking, "
          f"{n['jumps'] / t:.2f} jumps; iterations {n['iterations'] / t:.2f} "
          f"({n['chances'] / n['iterations']:.2f}x fewer than chances); jump folded into the step before: "
          f"{n['folded'] / t:.2f}; jumps only at trial starts: {n['start_only'] / t:.2f}")


if __name__ == "__main__":
    main()
