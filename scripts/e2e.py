"""End-to-end wall times of whole `jaxeac` commands, as quoted in BENCHMARKS.md.

    python scripts/e2e.py --out runs/e2e        # all three; or name some: --only grid sweep

Each command runs in its own process (compile, run, statistics and figures included).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ALPHAS = "0.02,0.05,0.1,0.15,0.2,0.3,0.4,0.5,0.7,0.9"
BETAS = "0.05,0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9"


def commands(out: Path) -> dict[str, list[str]]:
    return {
        "grid": ["grid", "--preset", "paper", "--seeds", "10000", "--out", str(out / "grid10k"), "--quiet"],
        "sweep": ["sweep", "--seeds", "1000", "--quiet", "--out", str(out / "sweep"),
                  "--set", f"alpha={ALPHAS}", "--set", f"beta={BETAS}"],  # 100 points × 2 algorithms
        "bowling": ["bowling", "--seeds", "1000", "--out", str(out / "bowling1000"), "--quiet"],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("runs/e2e"))
    p.add_argument("--only", nargs="+", choices=["grid", "sweep", "bowling"])
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    timings = {}
    for name, argv in commands(args.out).items():
        if args.only and name not in args.only:
            continue
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "jaxeac", *argv], check=True, stdout=subprocess.DEVNULL)
        timings[name] = {"command": " ".join(["jaxeac", *argv]), "wall_s": time.perf_counter() - t0}
        print(json.dumps({name: timings[name]}), flush=True)
    (args.out / "timings.json").write_text(json.dumps(timings, indent=2) + "\n")


if __name__ == "__main__":
    main()
