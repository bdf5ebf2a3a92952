"""Cumulative successes over trials from per-trial counts: the learning curves of Fig. 3 and the
study's figure, computed without matplotlib (in the process that holds the runs' results; a figure
may be drawn elsewhere, `jaxeac.running.helper`).

`cumulative_counts` counts, per trial, how many seeds have each number of successes so far;
`cumulative_lines` turns those counts into each curve's mean, the 95 % CI of the mean and the
seeds' 5-95 % spread.
"""

from __future__ import annotations

import os

import numpy as np

from jaxeac.stats.closed_form import t_half_width


def _prefix_popcounts() -> np.ndarray:
    """uint8 [9, 256]: row j, column b: how many of byte b's lowest j bits are set."""
    low_first = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1, bitorder="little")
    return np.concatenate([np.zeros((1, 256), np.uint8), np.cumsum(low_first, axis=1).T]).astype(np.uint8)


_PREFIX = _prefix_popcounts()


#: `cumulative_counts` counts at most this many seed-trials directly (the packed histogram's fixed
#: cost, about 0.1 s a call, is 80x the direct count at 1,000 x 200; at 10^5 x 200 it is 5x faster)
DIRECT_CELLS = 1 << 20


def cumulative_counts(success, chunk: int = 1 << 14) -> np.ndarray:
    """int64 [T, T + 1]: per trial t, how many seeds have v successes in trials 1..t (exact).

    `success`: bool [N, T] or `SuccessBits`. Up to `DIRECT_CELLS` seed-trials, one histogram of
    (trial, running count). Beyond, it works on the packed bits, eight trials a byte: a
    seed's count after trial 8b + j is its count before byte b plus the set bits among byte b's
    lowest j + 1, so one histogram of (byte position, count before it, byte value) per block of
    `chunk` seeds, on host threads, gives every trial's counts: N·T/8 entries instead of N·T,
    and no unpacking. Temporaries ~ 50 bytes a seed per thread."""
    from concurrent.futures import ThreadPoolExecutor

    from jaxeac.bits import SuccessBits

    n, t = success.shape
    if n * t <= DIRECT_CELLS:  # one cumsum and one histogram of (trial, count): 1.2 ms at 1,000 x 200
        cells = success.rows() if isinstance(success, SuccessBits) else np.asarray(success, bool)
        at = np.arange(t, dtype=np.int64) * (t + 1) + np.cumsum(cells, axis=1, dtype=np.int64)
        return np.bincount(at.ravel(), minlength=t * (t + 1)).reshape(t, t + 1)
    bits = success if isinstance(success, SuccessBits) else SuccessBits.pack(success)
    nb = bits.bits.shape[1]
    width = nb * (t + 1) * 256  # bins: (byte position, count before it, byte value)
    start_of = (np.arange(nb, dtype=np.int64) * (t + 1) * 256)[None, :]

    def block(start: int) -> np.ndarray:  # numpy frees the GIL in take, cumsum and bincount
        b = bits.bits[start:start + chunk]
        before = np.cumsum(_PREFIX[8].take(b), axis=1, dtype=np.int64)
        before -= _PREFIX[8].take(b)  # exclusive: the count before each byte
        return np.bincount((start_of + before * 256 + b).ravel(), minlength=width)

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        joint = sum(pool.map(block, range(0, n, chunk)), np.zeros(width, np.int64))
    joint = joint.reshape(nb, t + 1, 256)
    counts = np.zeros((nb, 8, t + 1 + 8), np.int64)
    for j in range(8):  # after trial 8b + j: the count before byte b plus its lowest j + 1 bits
        ones = _PREFIX[j + 1]
        for p in range(j + 2):
            counts[:, j, p:p + t + 1] += joint[:, :, ones == p].sum(axis=2)
    return counts.reshape(nb * 8, t + 1 + 8)[:t, :t + 1]


def count_percentile(counts: np.ndarray, q: float) -> np.ndarray:
    """Per row, the q-th percentile of the values 0..V counted in `counts` [rows, V + 1], by
    numpy's default (linear) rule on the sorted values: exact from the counts."""
    n = int(counts[0].sum())
    cdf = np.cumsum(counts, axis=1)
    pos = q / 100 * (n - 1)
    lo = int(np.floor(pos))

    def order_statistic(k):  # the k-th smallest value (0-based) per row
        return np.argmax(cdf > k, axis=1)

    a, b = order_statistic(lo), order_statistic(min(lo + 1, n - 1))
    return a + (b - a) * (pos - lo)


def cumulative_lines(counts: np.ndarray, *, spread: bool = False) -> dict[str, np.ndarray | int | None]:
    """One curve's lines from `counts`, int [T, T + 1] (`cumulative_counts`) of n seeds: ``n``;
    ``mean`` cumulative successes per trial [T]; ``half`` the half-width of its 95 % CI (None for
    one seed); with `spread`, ``low`` and ``high``, the seeds' 5th and 95th percentiles [T] (None
    for one seed)."""
    counts = np.asarray(counts)
    if counts.ndim != 2 or counts.shape[1] != counts.shape[0] + 1:
        raise ValueError(f"counts must be [T, T + 1]: per trial, seeds per number of successes so far "
                         f"(cumulative_counts); got shape {counts.shape}")
    n = int(counts[0].sum())
    values = np.arange(counts.shape[1])
    mean = counts @ values / n
    half = low = high = None
    if n > 1:
        sd = np.sqrt((counts * (values[None, :] - mean[:, None]) ** 2).sum(axis=1) / (n - 1))
        half = t_half_width(sd, n)
        if spread:
            low, high = count_percentile(counts, 5), count_percentile(counts, 95)
    return {"n": n, "mean": mean, "half": half, "low": low, "high": high}
