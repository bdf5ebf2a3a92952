"""A run's success curves packed eight trials a byte, and the per-seed measures of results.parquet.

`SuccessBits` is the layout of ``success_bits`` in a run folder's results.parquet
(`jaxeac.results`) and what the runner keeps of a streamed run's curves
(`jaxeac.running.outputs.CompactCollector`); the statistics (`jaxeac.stats`) and the figures
(`jaxeac.plots`) read it. Plain data on NumPy: it imports nothing of the package, so every
layer may use it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np


@dataclasses.dataclass(frozen=True)
class SuccessBits:
    """Success per trial of N seeds, eight trials a byte: bit t of row i (low bit first,
    ``np.packbits(..., bitorder="little")``) is trial t of seed i.

    1/8 of the bool matrix [N, T] and the layout of ``success_bits`` in results.parquet,
    so a run folder loads without a copy. Code that needs bools unpacks `blocks` of
    rows, so temporaries stay bounded whatever N.
    """

    bits: np.ndarray  # uint8 [N, ceil(T / 8)]
    trials: int

    BLOCK = 1 << 16  # rows per unpacked block

    @classmethod
    def pack(cls, success: np.ndarray) -> SuccessBits:
        success = np.asarray(success, bool)
        return cls(np.packbits(success, axis=1, bitorder="little"), success.shape[1])

    @property
    def shape(self) -> tuple[int, int]:
        return (self.bits.shape[0], self.trials)

    def __len__(self) -> int:
        return self.bits.shape[0]

    def rows(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """bool [stop − start, T]: the rows start … stop − 1 unpacked."""
        return np.unpackbits(self.bits[start:stop], axis=1, count=self.trials, bitorder="little").view(bool)

    def blocks(self, size: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """(first row, bool rows) for blocks of `size` rows (default `BLOCK`)."""
        size = size or self.BLOCK
        for start in range(0, len(self), size):
            yield start, self.rows(start, start + size)

    def column(self, t: int) -> np.ndarray:
        """bool [N]: trial t of every seed."""
        return (self.bits[:, t // 8] >> (t % 8)) & 1 == 1

    def unpack(self) -> np.ndarray:
        return self.rows()

    def column_sums(self) -> np.ndarray:
        """float64 [T]: successes per trial over the seeds (exact)."""
        total = np.zeros(self.trials, np.int64)
        for _, rows in self.blocks():
            total += np.count_nonzero(rows, axis=0)
        return total.astype(np.float64)


def trial_masks(width: int, trials: int, late: int) -> tuple[np.ndarray, np.ndarray]:
    """uint8 [width] each: per byte of a row of `SuccessBits.bits`, its bits that are trials, and
    those of the last `late` trials (bit b of byte j is trial 8j + b)."""
    position = 8 * np.arange(width)[:, None] + np.arange(8)  # [bytes, 8] trial of each bit
    keep = np.packbits(position < trials, axis=1, bitorder="little")[:, 0]
    in_late = np.packbits((position >= trials - late) & (position < trials), axis=1, bitorder="little")[:, 0]
    return keep, in_late


def as_bool(success) -> np.ndarray:
    """bool [N, T] from a bool matrix or `SuccessBits`."""
    return success.unpack() if isinstance(success, SuccessBits) else np.asarray(success, bool)


def measures_of(success: np.ndarray, steps: np.ndarray, finite=None) -> dict:
    """The per-seed columns of rows with success bool [M, T] and steps [M, T] (results.parquet's)."""
    any_success = success.any(axis=1)
    return {"bits": np.packbits(success, axis=1, bitorder="little"),
            "successes": np.count_nonzero(success, axis=1),
            "first_success": np.where(any_success, success.argmax(axis=1) + 1, -1),
            "steps_total": np.asarray(steps).sum(axis=1, dtype=np.int64),
            "finite": np.ones(success.shape[0], bool) if finite is None else np.asarray(finite, bool)}
