"""How long a `jaxeac grid` command takes to start: JAX imported, the command's modules imported,
the devices ready, with the devices started after the imports (as `jaxeac` does) or on a
thread beside them (a way tried and not taken: BENCHMARKS.md, *starting the devices beside the
imports*).

    python scripts/startup.py --repeats 4 --out startup.json

Each measurement is a fresh process (``--child serial`` or ``--child thread``), the two ways
taking turns. Seconds are from the child's start; the first pair also pays for cold files
and, in a machine's first process, a cold driver.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

T0 = time.perf_counter()


def child(mode: str) -> dict:
    from jaxeac.runtime import configure

    configure_xla("grid")
    import jax

    jax_s = time.perf_counter() - T0
    thread = threading.Thread(target=jax.devices) if mode == "thread" else None
    if thread is not None:
        thread.start()
    import jaxeac.experiments.grid  # noqa: F401  (what `jaxeac grid` imports before its run)
    import jaxeac.running.batch  # noqa: F401
    import jaxeac.stats.large  # noqa: F401
    import jaxeac.stats.run  # noqa: F401

    imports_s = time.perf_counter() - T0
    if thread is not None:
        thread.join()
    devices = jax.devices()
    return {"mode": mode, "jax_imported_s": jax_s, "modules_imported_s": imports_s,
            "devices_ready_s": time.perf_counter() - T0, "device": str(devices[0].device_kind)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=4, help="pairs of processes, the modes taking turns")
    p.add_argument("--out", type=Path, help="write the JSON record here")
    p.add_argument("--child", choices=["serial", "thread"], help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        print(json.dumps(child(args.child)))
        return
    if args.repeats < 1:
        p.error("--repeats must be ≥ 1")
    rows = []
    for i in range(args.repeats):
        for mode in ("serial", "thread"):
            t0 = time.perf_counter()
            out = subprocess.run([sys.executable, __file__, "--child", mode], check=True, capture_output=True,
                                 text=True).stdout
            row = json.loads(out.strip().splitlines()[-1]) | {"round": i, "process_wall_s": time.perf_counter() - t0}
            print(json.dumps(row), flush=True)
            rows.append(row)
    if args.out:
        command = "python scripts/startup.py " + " ".join(sys.argv[1:])
        args.out.write_text(json.dumps({"command": command, "python": sys.version.split()[0], "rows": rows},
                                       indent=1) + "\n")


if __name__ == "__main__":
    main()
