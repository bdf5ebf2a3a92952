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


@pytest.mark.parametrize("together", [True, False])
def test_binned_draws_of_many_groups_are_each_group_own(monkeypatch, together):
    """`boot_counts_binned` (several groups' draws in one program, or one call per group where
    `BINNED_TOGETHER` says so): each group's own key gives its own `boot_counts`, and one shared
    key gives one draw counted per each group's bins, bit for bit; batches split by
    `MAX_CHUNK_ELEMENTS` change nothing."""
    monkeypatch.setattr(resample, "BINNED_TOGETHER", {jax.default_backend(): together})
    rng = np.random.default_rng(3)
    n, r = 120, 70
    bins = [np.unique(rng.integers(0, d, n), return_inverse=True)[1].astype(np.int32) for d in (2, 9, 40)]
    keys = [jax.random.fold_in(jax.random.key(4), j) for j in range(3)]
    own = [boot_counts(k, n, r, chunk=30, units_first=True, bins=b) for k, b in zip(keys, bins, strict=True)]
    shared = [boot_counts(keys[0], n, r, chunk=30, units_first=True, bins=b) for b in bins]
    for step in (10**9, 30 * n):  # all groups in one batch; one group a batch
        monkeypatch.setattr(resample, "MAX_CHUNK_ELEMENTS", step)
        for got, want in ((resample.boot_counts_binned(keys, n, r, bins, chunk=30), own),
                          (resample.boot_counts_binned(keys[0], n, r, bins, chunk=30), shared)):
            assert [g.shape for g in got] == [w.shape for w in want]
            for g, w in zip(got, want, strict=True):
                np.testing.assert_array_equal(g, w)
    assert not np.array_equal(own[1], shared[1])  # the keys matter
