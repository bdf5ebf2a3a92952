"""`resample.boot_counts` with `bins`: the raw bootstrap draws of the units, counted per bin on the
device, equal the per-unit counts summed over each bin's units (SPEC §6), for bins in any order and
any number of them; programs are shared per power-of-two bucket of bins, not compiled per width."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxeac.stats import resample
from jaxeac.stats.resample import boot_counts


@pytest.mark.parametrize(("n", "distinct", "ordered"), [(100, 3, True), (1000, 17, False), (300, 300, True),
                                                        (500, 33, False), (7, 1, True)])
def test_counts_per_bin_are_the_units_counts_summed(n, distinct, ordered):
    rng = np.random.default_rng(n + distinct)
    x = rng.integers(0, distinct, n)
    x = np.sort(x) if ordered else x
    _, bins = np.unique(x, return_inverse=True)
    key = jax.random.key(5)
    units = boot_counts(key, n, 250, chunk=100, units_first=True)
    want = np.zeros((bins.max() + 1, 250), np.float32)
    np.add.at(want, bins, units)
    got = boot_counts(key, n, 250, chunk=100, units_first=True, bins=bins.astype(np.int32))
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(boot_counts(key, n, 250, chunk=100, bins=bins.astype(np.int32)), want.T)
    assert got.sum(axis=0).tolist() == [n] * 250


def test_bin_counts_compile_once_per_bucket():
    resample._counts_chunk_t.clear_cache()
    key = jax.random.key(0)
    for width in (17, 20, 25, 32):  # one bucket: 32
        boot_counts(key, 64, 20, chunk=20, units_first=True, bins=np.arange(64, dtype=np.int32) % width)
    assert resample._counts_chunk_t._cache_size() == 1
