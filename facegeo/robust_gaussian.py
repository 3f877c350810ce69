"""A Gaussian fitted to samples with outliers in them, and the χ² quantiles that its trimming needs.

:func:`robust_gaussian` starts from the median and the MAD and re-estimates the mean and
covariance on the samples inside the 97.5 % χ² ellipsoid of the previous estimate; the
covariance of a Gaussian truncated there is smaller than the whole one's by
P(χ²_{D+2} ≤ c) / P(χ²_D ≤ c), which is divided back out. Used by the photo's skin-colour model
(:mod:`facegeo.skin_mask`, D = 2) and the texture stage's seen-skin colour (D = 3).

The χ² distribution function is written out (the regularised lower incomplete gamma function at
integer and half-integer shape has closed forms) because importing ``scipy.stats`` costs
``facegeo reconstruct`` a few tenths of a second; the tests compare it with SciPy's.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["chi2_cdf", "chi2_quantile", "mahalanobis_squared", "robust_gaussian"]

#: The share of a Gaussian's samples kept by each trimming round.
TRIM_QUANTILE = 0.975


def chi2_cdf(x: float, dof: int) -> float:
    """P(χ² ≤ ``x``) for ``dof`` ≥ 1 degrees of freedom (float64 accuracy)."""
    if dof < 1:
        raise ValueError(f"dof: expected a positive integer, got {dof}")
    if x <= 0.0:
        return 0.0
    h = 0.5 * x
    if dof % 2 == 0:  # P(k, h) = 1 − e^{−h} Σ_{i<k} h^i / i!
        term, total = 1.0, 1.0
        for i in range(1, dof // 2):
            term *= h / i
            total += term
        return max(0.0, 1.0 - math.exp(-h) * total)
    # P(k + 1/2, h) = erf(√h) − e^{−h} Σ_{i<k} h^{i+1/2} / Γ(i + 3/2)
    term = math.sqrt(h) / math.gamma(1.5)
    total = 0.0
    for i in range(dof // 2):
        total += term
        term *= h / (i + 1.5)
    return max(0.0, math.erf(math.sqrt(h)) - math.exp(-h) * total)


def chi2_quantile(p: float, dof: int) -> float:
    """The x with P(χ² ≤ x) = ``p`` in (0, 1) for ``dof`` degrees of freedom (bisection to 1e-10)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p: expected a probability in (0, 1), got {p}")
    lo, hi = 0.0, float(dof) + 10.0 * math.sqrt(2.0 * dof) + 50.0
    while hi - lo > 1e-10 * max(1.0, hi):
        mid = 0.5 * (lo + hi)
        if chi2_cdf(mid, dof) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def mahalanobis_squared(x: np.ndarray, mean: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(..., D) points -> (...) float64 squared Mahalanobis distances from ``mean`` (D,) under
    ``covariance`` (D, D)."""
    d = np.asarray(x, np.float64) - mean
    return np.einsum("...i,ij,...j->...", d, np.linalg.inv(covariance), d)


def robust_gaussian(samples: np.ndarray, rounds: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Mean (D,) and covariance (D, D) float64 of (N, D) samples, re-estimated ``rounds`` times
    on the points inside the :data:`TRIM_QUANTILE` χ² ellipsoid of the previous estimate,
    starting from the median and the MAD (each axis at least 1e-3); a round that would keep
    fewer than 10 points stops the re-estimation."""
    samples = np.asarray(samples, np.float64)
    dim = samples.shape[1]
    cut = chi2_quantile(TRIM_QUANTILE, dim)
    kept_variance = chi2_cdf(cut, dim + 2) / TRIM_QUANTILE  # a truncated Gaussian's variance over the whole one's
    mean = np.median(samples, axis=0)
    mad = 1.4826 * np.median(np.abs(samples - mean), axis=0)
    cov = np.diag(np.maximum(mad, 1e-3) ** 2)
    for _ in range(rounds):
        inliers = samples[mahalanobis_squared(samples, mean, cov) < cut]
        if len(inliers) < 10:
            break
        mean = inliers.mean(axis=0)
        cov = np.cov(inliers.T) / kept_variance + np.eye(dim) * 1e-6
    return mean, cov
