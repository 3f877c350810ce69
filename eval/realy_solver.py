"""The linear solves of REALY's non-rigid ICP: the normal equations ``A^T A X = A^T B`` of each step.

Every step of the non-rigid ICP solves one symmetric positive definite system of size 4N (N
region vertices) with three right-hand sides; its sparsity pattern is the same at every step of
a region, its values are not (they hold the current deformed vertices). The systems come with
their unknowns already in a fill-reducing (nested-dissection) order. Two backends:

* ``"cholmod"``: CHOLMOD's supernodal Cholesky factorisation, as in the official code (which
  calls scikit-sparse's ``cholesky`` at every step). Reached through CVXOPT's ``cvxopt.cholmod``
  (the optional extra ``facegeo[cholmod]``; CVXOPT is GPL-3, and so is CHOLMOD's supernodal
  module), whose wheels bundle an optimised BLAS: the numeric factorisation of a 23,744-unknown
  system takes 33 ms there against 210 ms with SuperLU and 270-350 ms with Debian's CHOLMOD on
  the reference BLAS (benchmarks/RESULTS.md). The symbolic analysis is done once per region,
  with the given order; every step gets a numeric factorisation and a direct solve.
* ``"superlu"``: SciPy's SuperLU, always available. Its factorisations are slow, so they are
  reused within a stiffness stage: the first system of a stage is factored, the later ones are
  solved by conjugate gradients from the previous solution, preconditioned by that factor, to
  ``rtol`` relative residual (past ``max_iterations`` the system is factored anew).

``"auto"`` (:func:`resolve`) takes CHOLMOD when CVXOPT can be imported. Both give the official
numbers: they differ by about 1e-11 relative in the solutions, which moves a REALY value only
through the near-ties that its reported uncertainty measures. A singular system (a part of the
region that nothing holds, where the official CHOLMOD call fails) raises
:class:`~facegeo.errors.FacegeoError`.
"""

from __future__ import annotations

import functools
import importlib
import time

import numpy as np
import scipy.sparse as sp

from facegeo.errors import FacegeoError
from facegeo.eval.realy_settings import SOLVERS

__all__ = ["cholmod_available", "resolve", "make_solver", "pcg", "CholmodSolver", "SuperLUSolver"]

_SINGULAR = ("the non-rigid ICP's linear system is singular: a part of the region has too few keypoints "
             "or matches to fix it (the official code fails here too)")

_NO_CVXOPT = "the 'cholmod' solver needs CVXOPT: pip install 'facegeo[cholmod]'"


@functools.cache
def cholmod_available() -> bool:
    """True when ``cvxopt.cholmod`` can be imported (it is then imported, with its BLAS)."""
    try:
        importlib.import_module("cvxopt.cholmod")
    except ImportError:
        return False
    return True


def resolve(solver: str) -> str:
    """The backend ``solver`` stands for: ``"auto"`` is ``"cholmod"`` when available, else ``"superlu"``.

    Raises FacegeoError for ``"cholmod"`` without CVXOPT, ValueError for an unknown name.
    """
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {', '.join(SOLVERS)}, not {solver!r}")
    if solver == "auto":
        return "cholmod" if cholmod_available() else "superlu"
    if solver == "cholmod" and not cholmod_available():
        raise FacegeoError(_NO_CVXOPT)
    return solver


def _column_norms(a: np.ndarray) -> np.ndarray:
    """(k,) Euclidean norms of the columns of a (n, k) array (one pass; np.linalg.norm per column is slower)."""
    return np.sqrt(np.einsum("ij,ij->j", a, a))


def _check_residual(matrix: sp.csc_matrix, x: np.ndarray, rhs: np.ndarray) -> None:
    """FacegeoError when a direct solution misses ``rhs`` by more than 1e-6 relative (near-singular)."""
    residual = float(np.sqrt(np.sum(_column_norms(matrix @ x - rhs) ** 2)))
    bound = max(float(np.sqrt(np.sum(rhs * rhs))), 1e-300)
    if not np.isfinite(residual) or residual > 1e-6 * bound:
        raise FacegeoError(f"{_SINGULAR} (relative residual {residual / bound:.1e})")


class _Solver:
    """Counts and CPU times shared by the backends (for REALY's ``details``)."""

    name = ""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray):
        self.indptr = indptr
        self.indices = indices
        self.size = len(indptr) - 1
        self.analyses = 0  # symbolic analyses (CHOLMOD) or 0
        self.factorisations = 0
        self.iterations: list[int] = []  # per solve: PCG iterations, 0 for a direct solve
        self.factor_seconds = 0.0
        self.solve_seconds = 0.0

    def matrix(self, data: np.ndarray) -> sp.csc_matrix:
        """The (4N, 4N) system with these values in the pattern's CSC slots (no copy)."""
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    def start_stage(self) -> None:
        """A new stiffness stage starts (SuperLU's reuse starts anew)."""

    def details(self) -> dict:
        return {"solver": self.name, "solves": len(self.iterations), "analyses": self.analyses,
                "factorisations": self.factorisations, "pcg_iterations": list(self.iterations),
                "factor_seconds": self.factor_seconds, "solve_seconds": self.solve_seconds}


class CholmodSolver(_Solver):
    """CHOLMOD (through CVXOPT): one matrix object and one symbolic analysis per solver, a numeric
    factorisation and a direct solve per system.

    ``indptr`` / ``indices``: the CSC pattern (both triangles, rows sorted in each column) of
    every system this solver gets, in its elimination order (the analysis keeps that order).
    """

    name = "cholmod"

    def __init__(self, indptr: np.ndarray, indices: np.ndarray):
        super().__init__(indptr, indices)
        if not cholmod_available():
            raise FacegeoError(_NO_CVXOPT)
        import cvxopt

        cols = np.repeat(np.arange(self.size), np.diff(indptr))
        self._lower = np.nonzero(indices >= cols)[0]  # CHOLMOD reads the lower triangle
        # the lower triangle as a CVXOPT matrix, built once (building it from the triplets sorts
        # them, 3 ms for 23,000 unknowns); each system only replaces its values (``V``, which
        # CVXOPT keeps in the same column-major order as the pattern's slots)
        self._matrix = cvxopt.spmatrix(cvxopt.matrix(0.0, (len(self._lower), 1)),
                                       cvxopt.matrix(np.asarray(indices[self._lower], dtype=np.int64)),
                                       cvxopt.matrix(cols[self._lower].astype(np.int64)), (self.size, self.size))
        self._symbolic = None

    def solve(self, data: np.ndarray, rhs: np.ndarray, x0: np.ndarray | None) -> np.ndarray:
        """(4N, k) solution of the system with values ``data`` (pattern slots) and right-hand sides ``rhs``."""
        import cvxopt
        import cvxopt.cholmod

        start = time.process_time()
        lower = self._matrix
        lower.V = cvxopt.matrix(data[self._lower])
        if self._symbolic is None:
            identity = cvxopt.matrix(np.arange(self.size, dtype=np.int64))
            self._symbolic = cvxopt.cholmod.symbolic(lower, p=identity)
            self.analyses += 1
        mid = time.process_time()
        try:
            cvxopt.cholmod.numeric(lower, self._symbolic)
        except ArithmeticError as exc:  # not positive definite
            raise FacegeoError(f"{_SINGULAR} ({exc})") from None
        done = time.process_time()
        self.factorisations += 1
        solution = cvxopt.matrix(np.asfortranarray(rhs, dtype=np.float64))
        cvxopt.cholmod.solve(self._symbolic, solution)
        x = np.array(solution).reshape(rhs.shape)
        _check_residual(self.matrix(data), x, rhs)
        self.iterations.append(0)
        self.factor_seconds += done - mid
        self.solve_seconds += (mid - start) + (time.process_time() - done)
        return x


def _superlu(matrix: sp.csc_matrix):
    """SuperLU factor of the SPD system (rows already in nested-dissection order), or FacegeoError.

    SciPy's SuperLU with the given order kept (``NATURAL``), no pivoting and symmetric mode: a
    Cholesky-like LU. With METIS' nested dissection of the vertex graph it factors these systems
    1.8x faster than with SuperLU's own minimum-degree order (benchmarks/RESULTS.md).
    """
    from scipy.sparse.linalg import splu

    try:
        # SuperLU's default relax / panel_size: larger ones (16 / 24) corrupted the heap here
        return splu(matrix, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError as exc:  # "Factor is exactly singular"
        raise FacegeoError(f"{_SINGULAR} ({exc})") from None


def pcg(matrix: sp.csc_matrix, rhs: np.ndarray, x0: np.ndarray, precondition, rtol: float,
        max_iterations: int) -> tuple[np.ndarray, int] | None:
    """Conjugate gradients on the (n, k) columns of ``rhs`` at once, from ``x0``, preconditioned.

    Written here because SciPy's ``cg`` takes one right-hand side at a time: the three columns
    share each preconditioner call (one triangular solve with three columns). Returns the
    solution and the iterations once every column's true residual is at most ``rtol`` times its
    right-hand side's norm, or None after ``max_iterations``.
    """
    x = x0.copy()
    r = rhs - matrix @ x
    goal = rtol * np.maximum(_column_norms(rhs), 1e-300)
    if np.all(_column_norms(r) <= goal):
        return x, 0
    z = precondition(r)
    p = z.copy()
    rz = np.einsum("ij,ij->j", r, z)
    for iteration in range(1, max_iterations + 1):
        ap = matrix @ p
        pap = np.einsum("ij,ij->j", p, ap)
        alpha = np.divide(rz, pap, out=np.zeros_like(rz), where=pap != 0)
        x += alpha * p
        r -= alpha * ap
        if np.all(_column_norms(r) <= goal):
            # the recurrence's residual drifts from the true one: confirm with the true residual
            if np.all(_column_norms(rhs - matrix @ x) <= goal):
                return x, iteration
            return None
        z = precondition(r)
        rz_new = np.einsum("ij,ij->j", r, z)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz != 0)
        p = z + beta * p
        rz = rz_new
    return None


class SuperLUSolver(_Solver):
    """SuperLU, with its factor reused within a stiffness stage (see the module doc).

    ``reuse=False`` factors every system.
    """

    name = "superlu"

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, reuse: bool = True, rtol: float = 1e-10,
                 max_iterations: int = 12):
        super().__init__(indptr, indices)
        self.reuse = reuse
        self.rtol = rtol
        self.max_iterations = max_iterations
        self._lu = None

    def start_stage(self) -> None:
        self._lu = None

    def solve(self, data: np.ndarray, rhs: np.ndarray, x0: np.ndarray | None) -> np.ndarray:
        """(4N, k) solution of the system with values ``data`` (pattern slots) and right-hand sides ``rhs``."""
        start = time.process_time()
        matrix = self.matrix(data)
        if self.reuse and self._lu is not None and x0 is not None:
            found = pcg(matrix, rhs, x0, self._lu.solve, self.rtol, self.max_iterations)
            if found is not None:
                self.solve_seconds += time.process_time() - start
                self.iterations.append(found[1])
                return found[0]
        mid = time.process_time()
        self._lu = _superlu(matrix)
        done = time.process_time()
        self.factor_seconds += done - mid
        self.factorisations += 1
        x = self._lu.solve(rhs)
        _check_residual(matrix, x, rhs)
        self.solve_seconds += (mid - start) + (time.process_time() - done)
        self.iterations.append(0)
        return x


def make_solver(solver: str, indptr: np.ndarray, indices: np.ndarray, reuse: bool = True,
                rtol: float = 1e-10) -> CholmodSolver | SuperLUSolver:
    """The backend named by ``solver`` (:data:`SOLVERS`) for systems of this CSC pattern.

    ``reuse`` / ``rtol``: SuperLU's factor reuse and its conjugate gradients' tolerance.
    """
    if resolve(solver) == "cholmod":
        return CholmodSolver(indptr, indices)
    return SuperLUSolver(indptr, indices, reuse, rtol)
