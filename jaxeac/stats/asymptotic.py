"""The asymptotically exact forms of the large-N path (`jaxeac.stats.large`, SPEC §6 "At very
many seeds"): ABC intervals (DiCiccio & Efron 1992), BCa on the bootstrap's normal limit, the
normal limit of the studentised permutation test (Janssen 1997). `large.resampling_path` says
when they are used (`large.ASYMPTOTIC`); the argument that they agree with the exact forms at
that N is in `jaxeac.stats.large`'s docstring.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from jaxeac.stats import closed_form as cf


def _column_sums(blocks) -> np.ndarray:
    """Column sums of consecutive blocks of rows [k, M > 1] as NumPy sums one C-ordered [n, M]
    array down its rows, one row after another: the blocks continue the same running sums, so
    the result is that of the whole array bit for bit, without it."""
    run = None
    for rows in blocks:
        run = np.add.reduce(rows if run is None else np.vstack([run, rows]), axis=0, keepdims=True)
    return run[0]


def _units_moments(z: np.ndarray, block: int = 1 << 16) -> tuple[np.ndarray, np.ndarray]:
    """``u.mean(0), u.std(0)`` of u = [z, z²] [n, 2] bit for bit, a block of rows at a time."""
    def units(i):
        zb = z[i : i + block]
        return np.stack([zb, zb * zb], 1)

    n = z.size
    mean = _column_sums(units(i) for i in range(0, n, block)) / n
    return mean, np.sqrt(_column_sums(np.square(units(i) - mean) for i in range(0, n, block)) / n)


def _two_sample_f(statistic: str, nb: int, nt: int):
    def f(theta):
        mb, qb, mt, qt = theta
        if statistic == "mean_diff":
            return mt - mb
        return cf.hedges_from_moments(nb, nb * mb, nb * qb, nt, nt * mt, nt * qt)

    return f


def _grad_hess(f, theta: np.ndarray, h: np.ndarray):
    """Central-difference gradient and Hessian of a smooth f: R^p -> R at theta."""
    p = theta.size
    f0 = float(f(theta))
    grad = np.empty(p)
    hess = np.empty((p, p))
    e = np.eye(p) * h
    for i in range(p):
        fp, fm = float(f(theta + e[i])), float(f(theta - e[i]))
        grad[i] = (fp - fm) / (2 * h[i])
        hess[i, i] = (fp - 2 * f0 + fm) / h[i] ** 2
        for j in range(i):
            v = (
                float(f(theta + e[i] + e[j]))
                - float(f(theta + e[i] - e[j]))
                - float(f(theta - e[i] + e[j]))
                + float(f(theta - e[i] - e[j]))
            ) / (4 * h[i] * h[j])
            hess[i, j] = hess[j, i] = v
    return f0, grad, hess


def abc_two_sample(statistic: str, x: np.ndarray, y: np.ndarray, alpha: float = 0.05) -> cf.Estimate:
    """ABC interval (DiCiccio & Efron 1992; `abcnon` of Efron & Tibshirani 1993, §22.6) for
    mean(y) − mean(x) ("mean_diff") or Hedges' g ("hedges_g"), the two samples resampled
    independently: `abc_intervals` of one statistic."""
    return abc_intervals((statistic,), x, y, alpha)[statistic]


def abc_intervals(statistics, x: np.ndarray, y: np.ndarray, alpha: float = 0.05) -> dict[str, cf.Estimate]:
    """`abc_two_sample` of each of `statistics`, from one pass over the units.

    Each statistic is a smooth function f of the group means of (x, x²); the empirical
    influence values, the acceleration, the bias and curvature corrections and the
    endpoints f(θ̂ + λδ) are all closed-form sums over the units (O(n)), taken one sample
    at a time so only one sample's per-unit temporaries exist at once. The means of (x, x²)
    and the centred units are computed once for all the statistics.
    """
    nb, nt = x.size, y.size
    moments = [_units_moments(z) for z in (x, y)]
    theta = np.r_[moments[0][0], moments[1][0]]
    sd = np.r_[moments[0][1], moments[1][1]]
    h = 1e-3 * np.where(sd > 0, sd, np.maximum(1e-8 * np.abs(theta), 1e-12))
    fs = {name: _two_sample_f(name, nb, nt) for name in statistics}
    derivs = {name: _grad_hess(f, theta, h) for name, f in fs.items()}
    parts = {name: [] for name in statistics}  # per side: sums of L², L³ and Q, and du^T L
    for k, (z, (mean, _)) in enumerate(zip((x, y), moments, strict=True)):
        du = np.empty((z.size, 2))  # [z, z²] less their means, made in place
        np.subtract(z, mean[0], out=du[:, 0])
        np.multiply(z, z, out=du[:, 1])
        du[:, 1] -= mean[1]
        gram = du.T @ du  # Σ_i du_i du_iᵀ: the quadratic terms Σ_i du_iᵀ H du_i are sums of H ∘ gram
        for name, (t0, grad, hess) in derivs.items():
            if not np.isfinite(t0):
                continue
            g_k, h_k = grad[2 * k : 2 * k + 2], hess[2 * k : 2 * k + 2, 2 * k : 2 * k + 2]
            L = du @ g_k
            L2 = np.square(L)
            l2, l3, dl = L2.sum(), np.dot(L2, L), du.T @ L  # (products, not pow: 10x faster)
            del L, L2
            parts[name].append((l2, l3, float((h_k * gram).sum()), dl, z.size))
        del du
    return {name: _abc_endpoints(fs[name], theta, *derivs[name], parts[name], alpha) for name in statistics}


def _abc_endpoints(f, theta: np.ndarray, t0: float, grad, hess, parts: list, alpha: float) -> cf.Estimate:
    """The ABC interval of f at theta from its derivatives and both sides' sums (`abc_intervals`)."""
    if not np.isfinite(t0):
        return cf.Estimate(t0, t0, t0, 1 - alpha)
    var = sum(l2 / n**2 for l2, _, _, _, n in parts)
    if not var > 0:
        return cf.Estimate(t0, t0, t0, 1 - alpha)
    sig = math.sqrt(var)
    a = sum(l3 / n**3 for _, l3, _, _, n in parts) / (6 * sig**3)
    direction = np.concatenate([dl / (n**2 * sig) for _, _, _, dl, n in parts])  # δ in θ-space
    bhat = sum(q / (2 * n**2) for _, _, q, _, n in parts)
    cq = direction @ hess @ direction / (2 * sig)
    curv = bhat / sig - cq
    z0 = special.ndtri(2 * special.ndtr(a) * special.ndtr(-curv))
    ends = []
    for q in (alpha / 2, 1 - alpha / 2):
        w = z0 + special.ndtri(q)
        lam = w / (1 - a * w) ** 2
        ends.append(float(f(theta + lam * direction)))
    return cf.Estimate(t0, min(ends), max(ends), 1 - alpha)


def normal_bca(est: float, jackknife: np.ndarray, alpha: float = 0.05) -> tuple[float, float]:
    """BCa endpoints with the bootstrap law replaced by its normal limit N(est, se²): z0 = 0,
    se and acceleration from the jackknife values (Efron 1987)."""
    jk = np.asarray(jackknife, np.float64)
    n = jk.size
    u = (n - 1) * (jk.mean() - jk)
    se = math.sqrt(((jk - jk.mean()) ** 2).sum() * (n - 1) / n)
    dens = (u**2).sum()
    a = (u**3).sum() / (6 * dens**1.5) if dens > 0 else 0.0
    out = []
    for q in (alpha / 2, 1 - alpha / 2):
        z = special.ndtri(q)
        out.append(est + se * z / (1 - a * z))
    return float(out[0]), float(out[1])


def normal_permutation_p(t_obs) -> np.ndarray:
    """Two-sided p of the studentised permutation test from its N(0, 1) limit (Janssen 1997)."""
    t = np.abs(np.asarray(t_obs, np.float64))
    return np.where(np.isfinite(t), 2 * special.ndtr(-t), 0.0)
