"""Draw the figures of BENCHMARKS.md from the records in scripts/bench_results/.

Reads only the kept records (each figure names the ones it uses) and writes four PNGs:

* ``throughput_vs_seeds.png``: useful agent-steps/s of the paper grid against seeds, on the
  2-core CPU and on one H100 (fused kernel and XLA ops);
* ``end_to_end_vs_seeds.png``: wall time of ``jaxeac grid --preset paper --seeds N`` (run,
  statistics report and figures) against N, first runs and cached;
* ``peers.png``: jaxeac against the peers measured in the same run (grid on the 2-core CPU:
  C, numba, NumPy; bowling: plain MuJoCo stepping, MuJoCo Warp, MJX in JAX);
* ``scaling.png``: the user's command on two GPUs over one (wall time, and the run phase per
  method) at 4M and 8M seeds, the build before and this one, against the ideal 2x.

Usage::

    python scripts/figures.py                          # into docs/benchmark_figures/
    python scripts/figures.py --records DIR --out DIR

Needs matplotlib only (no JAX).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECORDS = ROOT / "scripts" / "bench_results"
OUT = ROOT / "docs" / "benchmark_figures"

COLORS = {"ac": "tab:blue", "eac": "tab:orange", "c": "tab:green", "numba": "tab:purple",
          "numpy": "tab:gray", "cpu": "tab:green", "gpu": "tab:red"}



def _save(fig, path: Path, title: str | None = None) -> Path:
    """Title, lay out, write at the page's resolution and close a figure; its path."""
    import matplotlib.pyplot as plt

    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path

def load(records: Path, name: str) -> dict:
    return json.loads((records / name).read_text())


def _jaxeac(rows: list[dict], algo: str, **match) -> list[dict]:
    out = [r for r in rows if r["impl"] == "jaxeac" and r["algo"] == algo
           and all(r.get(k, v) == v for k, v in match.items())]
    return sorted(out, key=lambda r: r["seeds"])


def _line(ax, rows, key="steps_per_s", **style):
    ax.plot([r["seeds"] for r in rows], [r[key] for r in rows], **style)


def throughput_vs_seeds(records: Path, out: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, (cpu, gpu) = plt.subplots(1, 2, figsize=(12, 6.2))
    rows = load(records, "cpu_grid_seeds.json")["rows"]
    for algo, label in (("ac", "AC"), ("eac", "EAC, before memory jumps")):
        _line(cpu, _jaxeac(rows, algo), marker="o", color=COLORS[algo],
              label=f"jaxeac {label} (cpu_grid_seeds.json: earlier build, a slower run)")
    for r in (r for r in rows if r["impl"] == "numpy"):
        cpu.plot(r["seeds"], r["steps_per_s"], marker="s", ls="none", color=COLORS["numpy"],
                 mfc="none" if r["algo"] == "eac" else COLORS["numpy"],
                 label=f"NumPy peer, {r['algo'].upper()} (same run as cpu_grid_seeds.json)")
    peers = load(records, "cpu_grid_peers.json")["rows"]
    for algo, label in (("ac", "jaxeac AC"), ("eac", "jaxeac EAC, memory jumps")):
        _line(cpu, _jaxeac(peers, algo), marker="*", ms=11, ls="--", color=COLORS[algo],
              label=f"{label} (cpu_grid_peers.json)")
    cpu.set_title("2-core CPU (cpu_grid_seeds.json, cpu_grid_peers.json)", fontsize=10)

    kernel = load(records, "gpu_h100_grid_seeds_kernel.json")["rows"]
    kernel8m = load(records, "gpu_h100_grid_8m.json")["rows"]
    xla = load(records, "gpu_h100_grid_seeds_xla.json")["rows"]
    for algo, name in (("ac", "AC"), ("eac", "EAC, no memory jumps")):
        _line(gpu, _jaxeac(kernel + kernel8m, algo), marker="o", color=COLORS[algo],
              label=f"jaxeac {name}, fused kernel")
        _line(gpu, _jaxeac(xla, algo), marker="o", ls=":", mfc="none", color=COLORS[algo],
              label=f"jaxeac {name}, XLA ops (same session)")
    for r in load(records, "gpu_h100_grid_4m.json")["rows"]:
        if r["impl"] == "jaxeac":
            name = "EAC, memory jumps" if r.get("jump") == "on" else "AC"
            gpu.plot(r["seeds"], r["steps_per_s"], marker="*", ms=14, ls="none", color=COLORS[r["algo"]],
                     mec="black", label=f"jaxeac {name}, default build (gpu_h100_grid_4m.json)")
    gpu.set_title("1× H100 (gpu_h100_grid_seeds_*.json, _8m, _4m)", fontsize=10)

    for ax in (cpu, gpu):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("seeds per run (paper preset, 200 trials)")
        ax.set_ylabel("useful agent-steps per second")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7.5, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=1, frameon=False)
    return _save(fig, out / "throughput_vs_seeds.png",
                 "Grid-world throughput against seeds (compile excluded; best of the record's repeats)")


def _builds_runs(record: dict) -> tuple[list[float], float]:
    """First-run and cached wall seconds of the last build a builds-taking-turns record names."""
    builds = record["grid"][0]["builds"]
    last = builds[list(builds)[-1]]
    return [r["wall_s"] for r in last["first_runs"]], last["cached"]["wall_s"]


def end_to_end_vs_seeds(records: Path, out: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 6.2))
    old = load(records, "cpu_e2e_grid_10k_100k.json")["grid"]
    ax.plot([g["seeds"] for g in old], [g["wall_s"] for g in old], marker="o", ls="--", mfc="none",
            color=COLORS["cpu"], label="2-core CPU, earlier build (cpu_e2e_grid_10k_100k.json)")
    first, cached = _builds_runs(load(records, "cpu_e2e_grid_100k.json"))
    ax.plot([1e5] * len(first), first, marker="o", ls="none", color=COLORS["cpu"],
            label="2-core CPU, first runs (cpu_e2e_grid_100k.json)")
    ax.plot(1e5, cached, marker="D", ls="none", color=COLORS["cpu"], mfc="none", ms=8,
            label="2-core CPU, compilation cache warm")

    first_1m, cached_1m = [], []
    for i in (1, 2, 3):
        f, c = _builds_runs(load(records, "gpu_h100_e2e_1m_first_runs.json")[f"machine_{i}"])
        first_1m += f
        cached_1m.append(c)
    ten = load(records, "gpu_h100_e2e_10m.json")
    first_10m, cached_10m = _builds_runs(ten)
    ax.plot([1e6] * len(first_1m) + [1e7] * len(first_10m), first_1m + first_10m, marker="o", ls="none",
            color=COLORS["gpu"], label="1× H100, first runs (gpu_h100_e2e_1m_first_runs.json, _10m)")
    ax.plot([1e6] * len(cached_1m) + [1e7], cached_1m + [cached_10m], marker="D", ls="none",
            color=COLORS["gpu"], mfc="none", ms=8, label="1× H100, compilation cache warm")
    one = load(records, "gpu_h100_e2e_1m.json")["grid"][0]
    ax.plot(1e6, one["compare_wall_s"], marker="^", ls="none", color="black", ms=8,
            label="1× H100, `jaxeac compare DIR` alone (gpu_h100_e2e_1m.json)")

    ax.axhline(15, color="gray", lw=0.8, ls=":")
    ax.text(6e3, 15.4, "15 s", color="gray", fontsize=8)
    ax.set_xscale("log")
    ax.set_xlim(5e3, 2e7)
    ax.set_ylim(0, 55)
    ax.set_xlabel("seeds per method (AC and EAC, paper preset)")
    ax.set_ylabel("wall time of the whole command, s")
    ax.set_title("`jaxeac grid --preset paper --seeds N`: run, statistics report and figures", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7.5, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=1, frameon=False)
    return _save(fig, out / "end_to_end_vs_seeds.png")


def _fmt(v: float) -> str:
    if v >= 1e5:
        mant, exp = f"{v:.2e}".split("e")
        return f"{float(mant):.2g}e{int(exp)}"
    return f"{v:,.0f}"


def _bars(ax, groups: list[str], series: list[tuple[str, str, list[float | None]]]) -> None:
    """Grouped bars; a series without a value in a group leaves no gap there."""
    width = 0.8 / max(sum(v[g] is not None for _, _, v in series) for g in range(len(groups)))
    labelled = set()
    for g in range(len(groups)):
        present = [(label, color, values[g]) for label, color, values in series if values[g] is not None]
        for i, (label, color, v) in enumerate(present):
            x = g + (i - (len(present) - 1) / 2) * width
            ax.bar(x, v, width, color=color, label=None if label in labelled else label)
            labelled.add(label)
            ax.text(x, v * 1.08, _fmt(v), ha="center", va="bottom", fontsize=7.5, rotation=90)
    ax.set_xticks(range(len(groups)), groups, fontsize=8.5)
    ax.set_yscale("log")


def peers(records: Path, out: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, (grid, bowl) = plt.subplots(1, 2, figsize=(13, 6.4), gridspec_kw={"width_ratios": [1.1, 1]})
    rows = load(records, "cpu_grid_peers.json")["rows"]
    keys = [(a, s) for a in ("ac", "eac") for s in (10_000, 100_000)]
    jax = {(r["algo"], r["seeds"]): r for r in rows if r["impl"] == "jaxeac"}
    npy = {(r["algo"], r["seeds"]): r["steps_per_s"] for r in rows if r["impl"] == "numpy"}
    groups = [f"{'AC' if a == 'ac' else 'EAC (jumps)'}\n{s:,} seeds" for a, s in keys]
    _bars(grid, groups, [
        ("jaxeac", COLORS["ac"], [jax[k]["steps_per_s"] for k in keys]),
        ("hand-written C (OpenMP)", COLORS["c"], [jax[k].get("c_steps_per_s") for k in keys]),
        ("numba (prange)", COLORS["numba"], [jax[k].get("numba_steps_per_s") for k in keys]),
        ("NumPy, hand-vectorised", COLORS["numpy"], [npy.get(k) for k in keys]),
    ])
    grid.set_ylabel("useful agent-steps per second")
    grid.set_ylim(5e6, 5e8)
    grid.set_title("Grid world, 2-core CPU, one run (cpu_grid_peers.json)", fontsize=10)
    grid.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, frameon=False)

    def pick(name, backend, physics, batch):
        return next(r["throws_per_s"] for r in load(records, name)["results"]
                    if (r["backend"], r["physics"], r["batch"]) == (backend, physics, batch))

    newton = "newton:4:8:32"
    cpu_c = load(records, "cpu_bowling_c.json")
    groups = ["2-core CPU\n1,024 throws\n(cpu_bowling_c.json)",
              "1× H100\n65,536 throws\n(gpu_h100_bowling_warp_vs_\nmujoco_warp.json)",
              "1× H100\n16,384 throws\n(gpu_h100_bowling_\nmjx_vs_warp.json)"]
    _bars(bowl, groups, [
        ("jaxeac (C engine, sleeping / MJX's Warp)", COLORS["ac"],
         [pick("cpu_bowling_c.json", "c", newton, 1024), pick("gpu_h100_bowling_warp_vs_mujoco_warp.json", "warp",
                                                              newton, 65536),
          pick("gpu_h100_bowling_mjx_vs_warp.json", "warp", newton, 16384)]),
        ("plain MuJoCo C, no sleeping (same run)", COLORS["c"],
         [next(r["throws_per_s"] for r in cpu_c["results"] if r["physics"].endswith("nosleep")
               and r["batch"] == 1024), None, None]),
        ("standalone mujoco-warp, sleeping (same run)", COLORS["numba"],
         [None, pick("gpu_h100_bowling_warp_vs_mujoco_warp.json", "mujoco_warp", newton, 65536), None]),
        ("standalone mujoco-warp, no sleeping (other run)", "plum",
         [None, pick("gpu_h100_bowling_mujoco_warp_nosleep.json", "mujoco_warp", newton + ":nosleep", 65536),
          None]),
        ("MJX in JAX (same run)", COLORS["numpy"],
         [None, None, pick("gpu_h100_bowling_mjx_vs_warp.json", "mjx", newton, 16384)]),
    ])
    bowl.set_ylabel("throws per second (400 physics steps of 5 ms each)")
    bowl.set_ylim(50, 5e4)
    bowl.set_title("Bowling, Newton 4/8 (the reference-accuracy default)", fontsize=10)
    bowl.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=2, frameon=False)
    return _save(fig, out / "peers.png", "jaxeac against peers measured in the same run")


SCALE_RECORD = "gpu_h100x2_grid_command_record.json"


def scaling(records: Path, out: Path) -> Path:
    """Two GPUs over one for the user's command (`scale.py --record`): wall time and the run
    phase per method, the build before and this one, against the ideal 2x."""
    import matplotlib.pyplot as plt

    runs = load(records, SCALE_RECORD)["runs"]
    builds = [(".dev_old", "the build before (f0551bf)", "tab:gray"), (".dev_new", "this build", COLORS["gpu"])]

    def ratio(build, step, seeds, key):
        one, two = ([r for r in runs[step] if r["build"] == build and r["seeds"] == seeds and r["visible"] == v]
                    for v in ("0", "0,1"))
        get = (lambda r: r[key]) if key == "wall_s" else (lambda r: r["per_algo"][key]["run_s"])
        return get(one[0]) / get(two[0])

    cases = [("wall\n4M", "cmd_main", 4194304, "wall_s"), ("wall\n8M", "cmd_main", 8388608, "wall_s"),
             ("wall, report\n4M", "cmd_report", 4194304, "wall_s"),
             ("AC run\n4M", "cmd_main", 4194304, "ac"), ("EAC run\n4M", "cmd_main", 4194304, "eac"),
             ("AC run\n8M", "cmd_main", 8388608, "ac"), ("EAC run\n8M", "cmd_main", 8388608, "eac")]
    fig, ax = plt.subplots(figsize=(8, 4.8))
    width = 0.38
    for i, (build, label, color) in enumerate(builds):
        xs = [g + (i - 0.5) * width for g in range(len(cases))]
        values = [ratio(build, step, n, key) for _, step, n, key in cases]
        ax.bar(xs, values, width, color=color, label=label)
        for x, v in zip(xs, values, strict=True):
            ax.text(x, v + 0.03, f"{v:.2f}", ha="center", va="bottom", fontsize=7.5)
    ax.axhline(2, color="black", ls=":", label="ideal (2x)")
    ax.axhline(1, color="black", lw=0.6)
    ax.set_xticks(range(len(cases)), [c[0] for c in cases], fontsize=8.5)
    ax.set_ylabel("two GPUs over one (time on one / time on two)")
    ax.set_ylim(0, 2.3)
    ax.set_title(f"jaxeac grid --preset paper (no report unless named), 2x H100, fresh processes ({SCALE_RECORD})",
                 fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3, axis="y")
    return _save(fig, out / "scaling.png")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(__doc__.splitlines()[2:]))
    ap.add_argument("--records", type=Path, default=RECORDS, help="folder of the records (default: %(default)s)")
    ap.add_argument("--out", type=Path, default=OUT, help="folder for the PNGs (default: %(default)s)")
    args = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    args.out.mkdir(parents=True, exist_ok=True)
    for draw in (throughput_vs_seeds, end_to_end_vs_seeds, peers, scaling):
        print(draw(args.records, args.out))


if __name__ == "__main__":
    main()
