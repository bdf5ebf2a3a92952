"""The bowling engines (SPEC B7) and the checks that one runs here: the C engine and MJX's two
implementations of the physics.

Apart from the engines themselves so that all sides ask it without importing each other:
`scene` (its settings) and `api` check a backend before any throw (importing MJX only for an MJX
backend), and `backend_mjx` runs the implementations.
"""

from __future__ import annotations

import contextlib
import io

from jaxeac.errors import UsageError

BACKENDS = ("c", "mjx", "warp")  # B7: C engine; MJX in JAX; MJX with its Warp implementation (NVIDIA GPUs)
MJX_IMPL = {"mjx": "jax", "warp": "warp"}  # the MJX implementation behind each MJX backend
IMPLS = ("jax", "warp")  # MJX implementations (B7)


def mjx_warp():
    """MJX's Warp module (`mujoco.mjx.warp`), imported quietly: MJX prints "Failed to import warp"
    without warp-lang."""
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco.mjx import warp
    return warp


def check_impl(impl: str) -> str:
    """Return impl if MJX offers it here, else raise UsageError naming the fix."""
    if impl not in IMPLS:
        raise UsageError(f"unknown MJX implementation {impl!r}: use one of {', '.join(IMPLS)}")
    if impl == "warp" and not mjx_warp().WARP_INSTALLED:
        raise UsageError('the warp backend needs warp-lang: pip install "jaxeac[warp]" (NVIDIA GPUs)')
    return impl


def default_backend() -> str:
    """B7's ``auto``: the fastest maintained engine where JAX runs: the C engine on CPUs; on
    accelerators MJX with its Warp implementation when warp-lang is installed, else MJX in JAX."""
    import jax

    if jax.default_backend() == "cpu":
        return "c"
    try:
        return check_backend("warp")
    except UsageError:
        return "mjx"


def check_backend(backend: str) -> str:
    """Return backend if known (``auto``: `default_backend`), else raise UsageError (B7)."""
    if backend == "auto":
        return default_backend()
    if backend not in BACKENDS:
        raise UsageError(f"unknown bowling backend {backend!r}: use one of auto, {', '.join(BACKENDS)}")
    if backend in MJX_IMPL:
        check_impl(MJX_IMPL[backend])  # imports MJX; only when an MJX backend is asked for
    return backend
