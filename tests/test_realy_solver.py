"""REALY's non-rigid ICP solver: factor reuse by preconditioned conjugate gradients, and the knobs."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from facegeo.errors import FacegeoError
from facegeo.eval.realy_align import EXACT, Settings
from facegeo.eval.realy_error import _factor, _pcg, _StageSolver


def _grid_system(n: int = 20, shift: float = 1.0, seed: int = 0) -> tuple[sp.csc_matrix, np.ndarray]:
    """An SPD system like the ICP's: a grid Laplacian (stiffness) plus positive per-unknown weights."""
    line = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    lap = sp.kronsum(line, line)
    weights = np.random.default_rng(seed).uniform(0.5, 1.5, n * n) * shift
    rhs = np.random.default_rng(seed + 1).normal(size=(n * n, 3))
    return sp.csc_matrix(lap + sp.diags(weights)), rhs


def test_pcg_preconditioned_by_an_earlier_factor_reaches_the_direct_solution():
    first, rhs = _grid_system(seed=0)
    second, _ = _grid_system(seed=2)  # other weights: the next step of a stage
    lu = _factor(first)
    found = _pcg(second, rhs, lu.solve(rhs), lu.solve, 1e-10, 50)
    assert found is not None
    x, iterations = found
    exact = np.column_stack([spsolve(second, rhs[:, k]) for k in range(3)])
    assert 0 < iterations <= 50
    assert np.abs(x - exact).max() <= 1e-8 * np.abs(exact).max()
    # its own factor needs no iteration from the exact answer, and a bad start needs more
    assert _pcg(second, rhs, exact, _factor(second).solve, 1e-10, 5) == (pytest.approx(exact), 0)
    assert _pcg(second, rhs, np.zeros_like(rhs), lu.solve, 1e-10, 1) is None


def test_stage_solver_reuses_the_factor_and_refactors_when_cg_is_slow():
    first, rhs = _grid_system(seed=0)
    near, _ = _grid_system(seed=2)
    far, _ = _grid_system(shift=1e4, seed=3)  # weights 1e4 times larger: the old factor is a poor guide
    solver = _StageSolver(reuse=True, rtol=1e-10, max_iterations=12)
    solver.start_stage()
    x = solver.solve(first, rhs, None)
    x = solver.solve(near, rhs, x)
    assert solver.factorisations == 1 and solver.iterations[0] == 0 and 0 < solver.iterations[1] <= 12
    x = solver.solve(far, rhs, x)
    assert solver.factorisations == 2 and solver.iterations[2] == 0
    assert np.abs(far @ x - rhs).max() <= 1e-8 * np.abs(rhs).max()
    solver.start_stage()  # a new stage starts with a factorisation
    solver.solve(near, rhs, x)
    assert solver.factorisations == 3
    plain = _StageSolver(reuse=False)
    plain.solve(first, rhs, None)
    plain.solve(near, rhs, x)
    assert plain.factorisations == 2 and plain.iterations == [0, 0]


def test_singular_system_is_an_error():
    singular = sp.csc_matrix(sp.diags([1.0, 1.0, 0.0]))
    with pytest.raises(FacegeoError, match="singular"):
        _StageSolver().solve(singular, np.ones((3, 3)), None)


def test_settings_default_is_the_official_protocol_and_checks_values():
    assert EXACT == Settings()
    assert (EXACT.rigid_tolerance, EXACT.rigid_max_updates, EXACT.nicp_epsilon_scale, EXACT.nicp_max_steps) == (
        1e-6, 100, 1.0, None)
    for bad in ({"solver_rtol": 0.0}, {"nicp_epsilon_scale": -1.0}, {"rigid_tolerance": float("nan")},
                {"nicp_max_steps": 0}, {"rigid_max_updates": -1}):
        with pytest.raises(ValueError):
            Settings(**bad)
