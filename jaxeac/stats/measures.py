"""The per-seed measures of a run (SPEC §6): the primary measure, fixed in advance (total
successes over T for the grid, total pins over T for bowling), and the secondary ones: success
rate over the last 20 % of trials, first successful trial (time to event, right-censored at T)
and the normalised area under the cumulative-success curve.

Above `large.LARGE_N` seeds a measure is kept as integer codes (`Coded`), counted per value
without float64 copies; `as_values`, `value_counts` and `event_counts` take either form.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from jaxeac.bits import SuccessBits, trial_masks
from jaxeac.errors import UsageError

LATE_FRACTION = 0.2
_BLOCK = 16_384  # seeds per block of the area sums
_COUNT_BLOCK = 1 << 20  # codes per block of the counts per value

# name -> (higher_is_better, description template)
MEASURES = {
    "successes": (True, "successful trials out of {T}"),
    "return": (True, "total pins over {T} trials"),
    "late_success_rate": (True, "success rate over the last {late} trials"),
    "first_success": (False, "first successful trial ({T1} if none)"),
    "auc_cumulative": (True, "area under the cumulative-success curve (0-1)"),
}


def late_window(trials: int) -> int:
    """Number of trials in the last 20 % (at least 1)."""
    return max(1, math.ceil(LATE_FRACTION * trials))


@dataclass(frozen=True)
class Coded:
    """A per-seed measure held as small integers: seed i's value is ``codes[i] / scale`` in
    float64 (no scale: the integer itself), the codes in the narrowest unsigned type (1 or 2
    bytes a seed instead of 8). `values` gives the float64 numbers the statistics read, seeds
    start … stop − 1 at a time if asked; `counts` the distinct values and their counts without
    a sort. Distinct codes give distinct values (integers below 2^24 over one scale)."""

    codes: np.ndarray
    scale: float | None = None

    @property
    def size(self) -> int:
        return self.codes.size

    def values(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        codes = self.codes[start:stop]
        return fill_values(Coded(codes, self.scale), np.empty(codes.size))

    def value_of(self, codes: np.ndarray) -> np.ndarray:
        return Coded(codes, self.scale).values()

    def counts(self, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(distinct values of seeds 0 … stop − 1, ascending, float64; their counts, int64)."""
        k = code_counts(self.codes[:stop], int(self.codes.max(initial=0)) + 1)
        present = np.flatnonzero(k)
        return self.value_of(present), k[present]


def code_counts(codes: np.ndarray, size: int) -> np.ndarray:
    """int64 [size]: how many of `codes` (integers in 0 … size − 1) equal each, counted a block
    at a time so the temporaries stay small."""
    k = np.zeros(size, np.int64)
    for i in range(0, codes.size, _COUNT_BLOCK):
        k += np.bincount(codes[i : i + _COUNT_BLOCK], minlength=size)
    return k


def fill_values(m, out: np.ndarray) -> np.ndarray:
    """Write the float64 values of a per-seed measure (an array or `Coded`) into `out`; returns it."""
    if isinstance(m, Coded):
        out[:] = m.codes
        if m.scale is not None:
            out /= m.scale
    else:
        out[:] = m
    return out


def as_values(m, start: int = 0, stop: int | None = None) -> np.ndarray:
    """float64 values of seeds start … stop − 1 of a per-seed measure: an array or `Coded`."""
    if isinstance(m, Coded):
        return m.values(start, stop)
    return np.asarray(np.asarray(m)[start:stop], np.float64)


def check_measure(m, name: str) -> None:
    """`closed_form.check_sample` for an array or `Coded` (whose values are finite by construction,
    so only its size is checked)."""
    from jaxeac.stats.closed_form import check_sample

    check_sample(m.values(0, 2) if isinstance(m, Coded) else m, name)


def value_counts(m, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(distinct values of seeds 0 … stop − 1, ascending; their counts, int64): of an array or `Coded`."""
    if isinstance(m, Coded):
        return m.counts(stop)
    values, counts = np.unique(np.asarray(m, np.float64)[:stop], return_counts=True)
    return values, counts.astype(np.int64)


def joint_counts(a: Coded, b: Coded) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct values of both (ascending, float64) and the counts of each in a and in b."""
    if a.scale != b.scale:
        raise ValueError(f"coded measures of different scales {a.scale} and {b.scale}")
    size = int(max(a.codes.max(initial=0), b.codes.max(initial=0))) + 1
    ka, kb = code_counts(a.codes, size), code_counts(b.codes, size)
    present = np.flatnonzero(ka + kb)
    return a.value_of(present), ka[present], kb[present]


def event_counts(time, event, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Log-rank categories of seeds 0 … stop − 1: (distinct times ascending [J], int64 [J]; counts
    int64 [2J], category 2j + e holding time j with event flag e). `time`: integers, or `Coded`."""
    event = np.asarray(event, bool)[:stop]
    if not isinstance(time, Coded):
        from jaxeac.stats.events import event_table

        return event_table(np.asarray(time)[:stop], event)
    codes = time.codes[:stop]
    k = np.zeros(2 * (int(codes.max(initial=0)) + 1), np.int64)
    for i in range(0, codes.size, _COUNT_BLOCK):
        k += np.bincount(2 * codes[i : i + _COUNT_BLOCK].astype(np.int64) + event[i : i + _COUNT_BLOCK],
                         minlength=k.size)
    pairs = k.reshape(-1, 2)
    present = np.flatnonzero(pairs.sum(1))
    return present, pairs[present].reshape(-1)


def _narrow_uint(largest: int) -> np.dtype:
    for dtype in (np.uint8, np.uint16, np.uint32):
        if largest <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.int64)


_BYTE_LOWEST = np.array([(v & -v).bit_length() - 1 if v else 8 for v in range(256)], np.int64)


def _codes_of_bits(bits: np.ndarray, trials: int, late: int) -> tuple[np.ndarray, ...]:
    """(successes, late successes, first success or T + 1, Σ_t success_t (T − t)) of rows of
    `SuccessBits.bits` (bit b of byte j is trial 8j + b), read from the bytes without unpacking
    them: per byte, its set bits and the sum of their positions, both from `np.bitwise_count`.
    Bits past the last trial are ignored. Exactly the unpacked rows' integers (tested)."""
    n, width = bits.shape
    keep, in_late = trial_masks(width, trials, late)
    bits = bits & keep
    per_byte = np.bitwise_count(bits)  # uint8 [n, bytes]
    count = per_byte.sum(1, dtype=np.int64)
    late_count = np.bitwise_count(bits & in_late).sum(1, dtype=np.int64)
    nonzero = bits != 0
    j = np.argmax(nonzero, axis=1)
    first = np.where(nonzero.any(1), 8 * j + _BYTE_LOWEST[bits[np.arange(n), j]] + 1, trials + 1)
    # Σ over set bits of (T − 8j − b) = Σ_j [count_j (T − 8j) − Σ b], where a byte x's Σ b
    # (at most 28) is |x & 0xAA| + 2|x & 0xCC| + 4|x & 0xF0|: the masks hold the positions b
    # whose bit 0, 1 and 2 is set
    positions = (np.bitwise_count(bits & np.uint8(0xAA)) + 2 * np.bitwise_count(bits & np.uint8(0xCC))
                 + 4 * np.bitwise_count(bits & np.uint8(0xF0)))
    area = per_byte.astype(np.int64) @ (trials - 8 * np.arange(width)) - positions.sum(1, dtype=np.int64)
    return count, late_count, first, area


def _on_device() -> bool:
    """Whether `SuccessBits` are read on an accelerator (`device_sums.device_codes`), not on host threads."""
    import jax

    return jax.default_backend() != "cpu"


def per_seed_codes(success, returns: np.ndarray | None = None) -> dict:
    """Per-seed measures from success [N, T] (bool, or `SuccessBits`) and pins [N, T] for
    bowling, primary first: {name: `Coded`} (bowling's return: float64 [N]), plus the log-rank
    inputs "_time" (first success, T + 1 if none: the codes of first_success) and "_event" (bool).

    Computed in blocks of `_BLOCK` seeds on host threads, so temporaries stay bounded whatever N;
    `SuccessBits` on an accelerator in one device program (`device_sums.device_codes`), the same
    integers.
    """
    packed = isinstance(success, SuccessBits)
    s = success if packed else np.asarray(success, bool)
    if len(s.shape) != 2:
        raise UsageError(f"success must be [seeds, trials], got shape {s.shape}")
    n, T = s.shape
    late = late_window(T)
    weights = np.arange(T, 0, -1)
    exact32 = T * (T + 1) // 2 < 2**24
    small = _narrow_uint(T + 1)
    count, late_count, first = (np.empty(n, small) for _ in range(3))
    area = np.empty(n, _narrow_uint(T * (T + 1) // 2))

    def block(i: int) -> None:  # numpy frees the GIL: blocks on host threads
        if packed:  # from the bytes (8 trials each), without unpacking them
            at = slice(i, min(i + _BLOCK, n))
            count[at], late_count[at], first[at], area[at] = _codes_of_bits(s.bits[at], T, late)
            return
        blk = s[i : i + _BLOCK]
        at = slice(i, i + blk.shape[0])
        count[at] = np.count_nonzero(blk, axis=1)
        late_count[at] = np.count_nonzero(blk[:, T - late :], axis=1)
        first[at] = np.where(blk.any(1), np.argmax(blk, 1) + 1, T + 1)
        # sum_t cumsum_t = sum_s success_s (T - s + 1), normalised by its maximum T(T+1)/2
        # (float32 products and sums of integers below 2^24: exact)
        area[at] = blk.astype(np.float32) @ weights.astype(np.float32) if exact32 else (blk * weights).sum(1)

    if packed and n and _on_device():  # 10^6 seeds of both methods: 0.26-0.30 s on host threads, 0.05-0.21 s
        from jaxeac.stats.device_sums import device_codes

        count, late_count, first, area = (a.astype(b.dtype) for a, b in zip(
            device_codes(s, late), (count, late_count, first, area), strict=True))
    else:
        with ThreadPoolExecutor(max_workers=min(os.cpu_count() or 1, -(-n // _BLOCK))) as pool:
            list(pool.map(block, range(0, n, _BLOCK)))
    out = {}
    if returns is None:
        out["successes"] = Coded(count)
    else:
        out["return"] = np.asarray(returns).sum(1).astype(np.float64)
    out["late_success_rate"] = Coded(late_count, float(late))
    out["first_success"] = Coded(first)
    out["auc_cumulative"] = Coded(area, T * (T + 1) / 2)
    out["_time"] = out["first_success"]
    out["_event"] = first <= T
    return out


def per_seed_measures(success, returns: np.ndarray | None = None) -> dict:
    """Per-seed measures from success [N, T] (bool, or `SuccessBits`) and pins [N, T] for
    bowling; primary first.

    Returns {name: float array [N]} plus the log-rank inputs under
    "_time" (first success, T + 1 if none) and "_event" (bool): `per_seed_codes` as numbers.
    """
    codes = per_seed_codes(success, returns)
    out = {k: as_values(v) for k, v in codes.items() if not k.startswith("_")}
    out["_time"] = codes["_time"].codes.astype(np.int64)
    out["_event"] = codes["_event"]
    return out


def describe(name: str, trials: int) -> str:
    return MEASURES[name][1].format(T=trials, late=late_window(trials), T1=trials + 1)


def last_trial(success) -> np.ndarray:
    """bool [N]: success in the final trial."""
    if isinstance(success, SuccessBits):
        return success.column(success.trials - 1)
    return np.asarray(success)[:, -1].astype(bool)
