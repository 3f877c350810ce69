"""A multifrontal sparse Cholesky for the non-rigid ICP's systems: one analysis, many factorings.

The REALY non-rigid ICP solves, for one scan region, ten to thirty symmetric positive definite
systems ``H X = R`` whose sparsity pattern never changes (4x4 blocks on the mesh's vertex graph).
SciPy has no sparse Cholesky (SuperLU factors them as general LU matrices and orders them anew each
time). :class:`BlockCholesky` analyses the pattern once (a nested-dissection ordering of the
vertex graph by recursive geometric bisection, and the assembly tree of dense fronts) and then
factors each matrix with dense LAPACK/BLAS kernels on the fronts (``potrf``, ``trsm``, ``syrk``
through NumPy/SciPy), which is several times faster than SuperLU here. The result is an exact
direct solve (rounding aside), like CHOLMOD's in the official code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

__all__ = ["BlockCholesky"]

_LEAF = 40  # vertices per leaf of the dissection


@dataclass
class _Node:
    pivots: np.ndarray  # scalar unknowns eliminated here
    front: np.ndarray  # scalar unknowns of the front: pivots then the update set
    children: list[int]
    assemble_src: np.ndarray = None  # positions in the matrix's data array
    assemble_dst: np.ndarray = None  # flat positions in the front (column-major pivot columns)
    child_maps: list[np.ndarray] = None  # for each child: its update rows' positions in this front


def _dissect(points: np.ndarray, adjacency: sp.csr_matrix) -> list[tuple[np.ndarray, list[int]]]:
    """Nested dissection: nodes (vertex set eliminated there, children) in postorder."""
    nodes: list[tuple[np.ndarray, list[int]]] = []

    def split(idx: np.ndarray) -> int:
        if len(idx) <= _LEAF:
            nodes.append((idx, []))
            return len(nodes) - 1
        p = points[idx]
        centred = p - p.mean(axis=0)
        axis = np.linalg.svd(centred, full_matrices=False)[2][0]
        proj = centred @ axis
        left = proj <= np.median(proj)
        if left.all() or not left.any():
            nodes.append((idx, []))
            return len(nodes) - 1
        sub = adjacency[idx][:, idx]
        touches_right = np.asarray(sub[:, ~left].sum(axis=1)).ravel() > 0
        sep = left & touches_right
        a, b = idx[left & ~sep], idx[~left]
        children = [split(part) for part in (a, b) if len(part)]
        nodes.append((idx[sep], children))
        return len(nodes) - 1

    # connected pieces are dissected independently
    from scipy.sparse.csgraph import connected_components

    _, label = connected_components(adjacency, directed=False)
    for piece in range(label.max() + 1):
        split(np.nonzero(label == piece)[0])
    return nodes


class BlockCholesky:
    """Cholesky factorisations of SPD matrices sharing one pattern of ``block x block`` blocks.

    ``vertex_adjacency``: the (n, n) vertex graph (the off-diagonal blocks that may be non-zero);
    ``points``: (n, 3) vertex positions, used only to order the unknowns; ``pattern``: a CSC
    matrix with the exact sparsity pattern (indices sorted), whose ``data`` layout the later
    :meth:`factor` calls must share.
    """

    def __init__(self, vertex_adjacency: sp.spmatrix, points: np.ndarray, pattern: sp.csc_matrix, block: int = 4):
        adjacency = sp.csr_matrix(vertex_adjacency, dtype=np.float64)
        adjacency = ((adjacency + adjacency.T) != 0).astype(np.float64).tocsr()
        n = adjacency.shape[0]
        raw = _dissect(np.asarray(points, dtype=np.float64), adjacency)
        order = np.concatenate([v for v, _ in raw])
        rank = np.empty(n, dtype=np.int64)
        rank[order] = np.arange(n)
        comp = np.arange(block)
        self.block = block
        self.size = n * block

        # update sets, bottom-up: neighbours of the subtree eliminated later
        nodes: list[_Node] = []
        subtree_done: list[set] = []
        last_rank = []
        for verts, children in raw:
            if len(verts):
                nbrs = np.unique(adjacency[verts].indices)
            else:
                nbrs = np.zeros(0, dtype=np.int64)
            cand = set(nbrs.tolist())
            for c in children:
                cand |= subtree_done[c]
            top = rank[verts].max() if len(verts) else max((last_rank[c] for c in children), default=-1)
            update = np.array(sorted(v for v in cand if rank[v] > top), dtype=np.int64)
            subtree_done.append(set(update.tolist()))
            last_rank.append(top)
            vorder = np.concatenate([verts[np.argsort(rank[verts])], update[np.argsort(rank[update])]])
            scalar = (vorder[:, None] * block + comp).ravel()
            nodes.append(_Node(pivots=scalar[: len(verts) * block], front=scalar, children=children))

        # assembly maps: the pattern's columns of each node's pivots, rows within its front
        pattern = sp.csc_matrix(pattern)
        indptr, indices = pattern.indptr, pattern.indices
        for node in nodes:
            nf = len(node.front)
            local = {int(u): k for k, u in enumerate(node.front)}
            src, dst = [], []
            for j, col in enumerate(node.pivots):
                lo, hi = indptr[col], indptr[col + 1]
                rows = indices[lo:hi]
                pos = np.array([local.get(int(r), -1) for r in rows])
                keep = pos >= 0
                src.append(np.arange(lo, hi)[keep])
                dst.append(pos[keep] + j * nf)  # column-major flat index (row pos, column j)
            node.assemble_src = np.concatenate(src) if src else np.zeros(0, dtype=np.int64)
            node.assemble_dst = np.concatenate(dst) if dst else np.zeros(0, dtype=np.int64)
            node.child_maps = []
            for c in node.children:
                child = nodes[c]
                upd = child.front[len(child.pivots):]
                node.child_maps.append(np.array([local[int(u)] for u in upd], dtype=np.int64))
        self.nodes = nodes
        self._factors = None

    def factor(self, matrix: sp.csc_matrix) -> BlockCholesky:
        """Factor a matrix with the analysed pattern (its ``data`` in the pattern's layout)."""
        data = matrix.data
        updates: dict[int, np.ndarray] = {}
        factors = []
        for i, node in enumerate(self.nodes):
            nf, p = len(node.front), len(node.pivots)
            front = np.zeros((nf, nf), order="F")
            flat = front.reshape(-1, order="F")
            np.add.at(flat, node.assemble_dst, data[node.assemble_src])
            for c, where in zip(node.children, node.child_maps):
                front[np.ix_(where, where)] += updates.pop(c)
            l11 = la.cholesky(front[:p, :p], lower=True, check_finite=False)
            if nf > p:
                l21 = la.solve_triangular(l11, front[p:, :p].T, lower=True, check_finite=False).T
                updates[i] = front[p:, p:] - l21 @ l21.T
            else:
                l21 = np.zeros((0, p))
            factors.append((l11, l21))
        self._factors = factors
        return self

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """Solve with the last factored matrix; ``rhs`` (size, k)."""
        x = np.array(rhs, dtype=np.float64, copy=True)
        for node, (l11, l21) in zip(self.nodes, self._factors):
            p = len(node.pivots)
            y = la.solve_triangular(l11, x[node.pivots], lower=True, check_finite=False)
            x[node.pivots] = y
            if len(l21):
                x[node.front[p:]] -= l21 @ y
        for node, (l11, l21) in zip(reversed(self.nodes), reversed(self._factors)):
            p = len(node.pivots)
            y = x[node.pivots]
            if len(l21):
                y = y - l21.T @ x[node.front[p:]]
            x[node.pivots] = la.solve_triangular(l11, y, lower=True, trans="T", check_finite=False)
        return x
