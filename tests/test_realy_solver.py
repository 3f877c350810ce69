"""REALY's non-rigid ICP solvers: CHOLMOD at every step, SuperLU with factor reuse by preconditioned
conjugate gradients, and the knobs."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from facegeo.errors import FacegeoError
from facegeo.eval.realy_settings import EXACT, Settings
from facegeo.eval import realy_solver
from facegeo.eval.realy_solver import SuperLUSolver, _superlu, make_solver, pcg, resolve


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
    lu = _superlu(first)
    found = pcg(second, rhs, lu.solve(rhs), lu.solve, 1e-10, 50)
    assert found is not None
    x, iterations = found
    exact = np.column_stack([spsolve(second, rhs[:, k]) for k in range(3)])
    assert 0 < iterations <= 50
    assert np.abs(x - exact).max() <= 1e-8 * np.abs(exact).max()
    # its own factor needs no iteration from the exact answer, and a bad start needs more
    assert pcg(second, rhs, exact, _superlu(second).solve, 1e-10, 5) == (pytest.approx(exact), 0)
    assert pcg(second, rhs, np.zeros_like(rhs), lu.solve, 1e-10, 1) is None


def _exact(matrix: sp.csc_matrix, rhs: np.ndarray) -> np.ndarray:
    return np.column_stack([spsolve(matrix, rhs[:, k]) for k in range(rhs.shape[1])])


def test_superlu_solver_reuses_the_factor_and_refactors_when_cg_is_slow():
    first, rhs = _grid_system(seed=0)
    near, _ = _grid_system(seed=2)
    far, _ = _grid_system(shift=1e4, seed=3)  # weights 1e4 times larger: the old factor is a poor guide
    assert np.array_equal(first.indices, far.indices)  # one pattern, other values
    solver = SuperLUSolver(first.indptr, first.indices, reuse=True, rtol=1e-10, max_iterations=12)
    solver.start_stage()
    x = solver.solve(first.data, rhs, None)
    x = solver.solve(near.data, rhs, x)
    assert solver.factorisations == 1 and solver.iterations[0] == 0 and 0 < solver.iterations[1] <= 12
    x = solver.solve(far.data, rhs, x)
    assert solver.factorisations == 2 and solver.iterations[2] == 0
    assert np.abs(far @ x - rhs).max() <= 1e-8 * np.abs(rhs).max()
    solver.start_stage()  # a new stage starts with a factorisation
    solver.solve(near.data, rhs, x)
    assert solver.factorisations == 3
    plain = SuperLUSolver(first.indptr, first.indices, reuse=False)
    plain.solve(first.data, rhs, None)
    plain.solve(near.data, rhs, x)
    assert plain.factorisations == 2 and plain.iterations == [0, 0]
    assert plain.details()["solver"] == "superlu" and plain.details()["analyses"] == 0


def test_cholmod_solver_analyses_once_and_factors_every_system():
    pytest.importorskip("cvxopt")
    first, rhs = _grid_system(seed=0)
    far, _ = _grid_system(shift=1e4, seed=3)
    solver = make_solver("cholmod", first.indptr, first.indices)
    for matrix in (first, far, first):
        x = solver.solve(matrix.data, rhs, None)
        exact = _exact(matrix, rhs)
        assert np.abs(x - exact).max() <= 1e-12 * np.abs(exact).max()
    d = solver.details()
    assert (d["solver"], d["analyses"], d["factorisations"], d["pcg_iterations"]) == ("cholmod", 1, 3, [0, 0, 0])
    # the two backends agree to rounding
    superlu = make_solver("superlu", first.indptr, first.indices)
    assert np.abs(superlu.solve(far.data, rhs, None) - solver.solve(far.data, rhs, None)).max() <= (
        1e-12 * np.abs(exact).max())


@pytest.mark.parametrize("backend", ["superlu", "cholmod"])
def test_singular_or_indefinite_system_is_an_error(backend):
    if backend == "cholmod":
        pytest.importorskip("cvxopt")
    # A^T A is never indefinite; CHOLMOD's Cholesky refuses one, SuperLU's LU does not need to
    for diagonal in ([1.0, 1.0, 0.0], [1.0, -1.0, 1.0])[: 2 if backend == "cholmod" else 1]:
        matrix = sp.csc_matrix(sp.diags(diagonal))
        solver = make_solver(backend, matrix.indptr, matrix.indices)
        with pytest.raises(FacegeoError, match="singular"):
            solver.solve(matrix.data, np.ones((3, 3)), None)


def test_auto_takes_cholmod_when_cvxopt_is_there(monkeypatch):
    assert resolve("superlu") == "superlu"
    with pytest.raises(ValueError, match="solver must be one of"):
        resolve("umfpack")
    monkeypatch.setattr(realy_solver, "cholmod_available", lambda: False)
    assert resolve("auto") == "superlu"
    with pytest.raises(FacegeoError, match=r"pip install 'facegeo\[cholmod\]'"):
        resolve("cholmod")
    monkeypatch.setattr(realy_solver, "cholmod_available", lambda: True)
    assert resolve("auto") == "cholmod"


def test_settings_default_is_the_official_protocol_and_checks_values():
    assert EXACT == Settings()
    assert (EXACT.rigid_tolerance, EXACT.rigid_max_updates, EXACT.nicp_epsilon_scale, EXACT.nicp_max_steps) == (
        1e-6, 100, 1.0, None)
    for bad in ({"solver_rtol": 0.0}, {"nicp_epsilon_scale": -1.0}, {"rigid_tolerance": float("nan")},
                {"nicp_max_steps": 0}, {"rigid_max_updates": -1}, {"solver": "umfpack"}):
        with pytest.raises(ValueError):
            Settings(**bad)
    # the solver and the factor reuse keep the official numbers; the other knobs loosen them
    assert Settings(solver="superlu", factor_reuse=False).loosened() == {}
    assert Settings(solver="superlu", nicp_max_steps=2).loosened() == {"nicp_max_steps": 2}
