"""Non-negative least squares for the few unknowns of the fill's noise
(:func:`~facegeo.texturing.default.noise.band_noise`: the power of each octave's layer)."""

from __future__ import annotations

import numpy as np

__all__ = ["nonnegative_least_squares"]


def nonnegative_least_squares(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin ‖a x − b‖ over x ≥ 0 for a small (m, n) ``a`` (n ≤ 8) and (m,) ``b``: (n,) float64.
    The optimum is the unconstrained least-squares solution on its own positive set, so the best
    feasible one over all 2ⁿ − 1 column sets is it. (By hand: scipy.optimize.nnls costs ~0.2 s of
    import in ``facegeo reconstruct``, for systems of three unknowns.)"""
    n = a.shape[1]
    if n > 8:
        raise ValueError(f"nonnegative_least_squares: expected at most 8 unknowns, got {n}")
    best, best_residual = np.zeros(n), float(b @ b)
    for subset in range(1, 1 << n):
        columns = [j for j in range(n) if subset >> j & 1]
        x = np.linalg.lstsq(a[:, columns], b, rcond=None)[0]
        if np.all(x >= 0):
            residual = float(np.sum((a[:, columns] @ x - b) ** 2))
            if residual < best_residual:
                best, best_residual = np.zeros(n), residual
                best[columns] = x
    return best
