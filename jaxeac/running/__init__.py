"""Running many seeds: `RunConfig` (resolved once), the per-seed loops, the fused GPU kernel, chunks,
and the memory diagnostics of a run's seeds (`jaxeac.running.diagnostics`, SPEC E8).

See docs/ARCHITECTURE.md for the flow of one run.
"""

from jaxeac.running.batch import run_entries, run_seeds
from jaxeac.running.config import RunConfig
from jaxeac.running.outputs import SeedsResult

__all__ = ["RunConfig", "SeedsResult", "run_entries", "run_seeds"]
