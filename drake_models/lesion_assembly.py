"""The lesion FEM's P1 forms and their assembly on a fixed sparsity pattern (issue 48).

The forms (axisymmetric, r-weighted; scikit-fem ``BilinearForm`` / ``LinearForm``, the definition):

- ``diffusion_form``: coef grad u . grad v r (the potential's sigma(T), the heat's k(T));
- ``mass_form``: coef u v r (the heat capacity);
- ``source_form``: q v r (a heat source given at the quadrature points).

``skfem.asm`` evaluates a form at every element's quadrature points and builds a new COO matrix
at each call. The lesion FEM assembles the diffusion and the source at every step on the same
mesh with new coefficients, and for P1 the rest of the integrand is fixed:

    K_ij = sum_e sum_q coef_eq (dx_eq r_eq grad phi_i . grad phi_j)     (dx: weight x Jacobian)
    f_i  = sum_e sum_q q_eq    (dx_eq r_eq phi_i(x_eq))

``P1Operators`` computes the bracketed products once (from the same ``CellBasis`` and the same
quadrature) as sparse matrices acting on the coefficient at the quadrature points: a step's
matrix is one sparse product giving the data array of a CSR pattern fixed once (every element's
node pairs and the diagonal). The free-node blocks the solves need (``OrderedBlock``) take their
upper triangles' entries from that data array through an index map computed once; the blocks are
symmetric positive definite, so each is factorised as LDL^T by QDLDL, whose fill-reducing order
(approximate minimum degree) and symbolic analysis are made once per block and reused by every
later step's numeric factorisation (docs/performance.md 32: about half of SuperLU's time). The
same discretisation as ``skfem.asm`` of the forms, summed in another order:
``tests/test_lesion_assembly.py`` checks the two agree to 1e-12, and the solves against scipy's.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import qdldl
from skfem import BilinearForm, CellBasis, LinearForm
from skfem.helpers import dot, grad


@BilinearForm
def diffusion_form(u, v, w):
    return w.coef * dot(grad(u), grad(v)) * w.x[0]


@BilinearForm
def mass_form(u, v, w):
    return w.coef * u * v * w.x[0]


@LinearForm
def source_form(v, w):
    return w.q * v * w.x[0]


class P1Operators:
    """The r-weighted P1 operators of one mesh, assembled from precomputed element products.

    Args:
        basis: the mesh's P1 ``CellBasis`` (its quadrature is the forms' quadrature).

    Attributes:
        n: number of nodes.
        indptr, indices: the CSR pattern (sorted columns; every element's node pairs and the diagonal).
        diagonal: (n,) position of each diagonal entry in the pattern's data.
    """

    def __init__(self, basis: CellBasis):
        t = np.asarray(basis.element_dofs)  # (3, ne): P1 dofs are the mesh's nodes
        n_loc, ne = t.shape
        nq = basis.X.shape[1]
        self.n = int(basis.N)
        self.shape_qp = (ne, nq)
        r_dx = np.asarray(basis.global_coordinates())[0] * np.asarray(basis.dx)  # (ne, nq)
        phi = np.stack([np.asarray(basis.basis[i][0]) for i in range(n_loc)])  # (3, ne, nq)
        dphi = np.stack([np.asarray(basis.basis[i][0].grad) for i in range(n_loc)])  # (3, 2, ne, nq)
        qp = np.arange(ne * nq).reshape(ne, nq)

        # The pattern: every (i, j) node pair of an element, and the diagonal.
        rows = np.concatenate([np.repeat(t, n_loc, axis=0).ravel(), np.arange(self.n)])
        cols = np.concatenate([np.tile(t, (n_loc, 1)).ravel(), np.arange(self.n)])
        pattern = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(self.n, self.n))
        pattern.sum_duplicates()
        pattern.sort_indices()
        self.indptr, self.indices = pattern.indptr, pattern.indices
        self.nnz = len(self.indices)
        self._key = np.repeat(np.arange(self.n, dtype=np.int64), np.diff(self.indptr)) * self.n + self.indices
        self._blocks: dict[bytes, OrderedBlock] = {}
        self.diagonal = self.positions(np.arange(self.n), np.arange(self.n))

        # Diffusion: data[k] = sum over (e, q) of coef_eq x (dx r grad phi_i . grad phi_j)_eq, k = pos(t_ie, t_je).
        pos = self.positions(np.repeat(t, n_loc, axis=0).ravel(), np.tile(t, (n_loc, 1)).ravel())
        pos = pos.reshape(n_loc, n_loc, ne)
        vals, at, of = [], [], []
        for i in range(n_loc):
            for j in range(n_loc):
                vals.append((r_dx * (dphi[i, 0] * dphi[j, 0] + dphi[i, 1] * dphi[j, 1])).ravel())
                at.append(np.repeat(pos[i, j], nq))
                of.append(qp.ravel())
        self._diffusion = sp.csr_matrix((np.concatenate(vals), (np.concatenate(at), np.concatenate(of))),
                                        shape=(self.nnz, ne * nq))
        # Source: f_i = sum over (e, q) of q_eq x (dx r phi_i)_eq.
        self._source = sp.csr_matrix(
            (np.concatenate([(r_dx * phi[i]).ravel() for i in range(n_loc)]),
             (np.concatenate([np.repeat(t[i], nq) for i in range(n_loc)]), np.tile(qp.ravel(), n_loc))),
            shape=(self.n, ne * nq))
        # Nodal values to the quadrature points, and each element's (constant) gradient.
        self._interpolate = sp.csr_matrix(
            (np.concatenate([phi[i].ravel() for i in range(n_loc)]),
             (np.tile(qp.ravel(), n_loc), np.concatenate([np.repeat(t[i], nq) for i in range(n_loc)]))),
            shape=(ne * nq, self.n))
        self._grad = [sp.csr_matrix((dphi[:, c, :, 0].T.ravel(), (np.repeat(np.arange(ne), n_loc), t.T.ravel())),
                                    shape=(ne, self.n)) for c in range(2)]

    def positions(self, rows, cols) -> np.ndarray:
        """Positions in the pattern's data of the entries (rows[k], cols[k]) (each must be in the pattern)."""
        target = np.asarray(rows, dtype=np.int64) * self.n + np.asarray(cols, dtype=np.int64)
        pos = np.searchsorted(self._key, target)  # the keys are sorted: rows ascending, columns sorted in each
        if np.any(pos >= self.nnz) or np.any(self._key[np.minimum(pos, self.nnz - 1)] != target):
            raise ValueError("an entry outside the mesh's sparsity pattern")
        return pos

    def diffusion(self, coef) -> np.ndarray:
        """The data array of the diffusion form's matrix with ``coef`` (ne, nq) at the quadrature points."""
        return self._diffusion @ np.asarray(coef, dtype=float).ravel()

    def source(self, q) -> np.ndarray:
        """The source form's load vector (n,) of ``q`` (ne, nq) at the quadrature points."""
        return self._source @ np.asarray(q, dtype=float).ravel()

    def at_quadrature(self, values) -> np.ndarray:
        """Nodal values (n,) interpolated to the quadrature points (ne, nq)."""
        return (self._interpolate @ values).reshape(self.shape_qp)

    def gradient(self, values) -> tuple[np.ndarray, np.ndarray]:
        """The (constant) gradient of nodal values on each element: (d/dr, d/dz), each (ne,)."""
        return self._grad[0] @ values, self._grad[1] @ values

    def data_of(self, matrix) -> np.ndarray:
        """A sparse matrix's entries as a data array of the pattern (its nonzeros must be in it)."""
        coo = sp.coo_matrix(matrix)
        data = np.zeros(self.nnz)
        np.add.at(data, self.positions(coo.row, coo.col), coo.data)
        return data

    def matrix(self, data) -> sp.csr_matrix:
        """The CSR matrix of a data array of the pattern."""
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))

    def block(self, rows) -> OrderedBlock:
        """The solver of the sub-matrix on ``rows`` (nodes; built once per row set and kept)."""
        rows = np.unique(np.asarray(rows, dtype=np.int64))
        key = rows.tobytes()
        if key not in self._blocks:
            self._blocks[key] = OrderedBlock(self, rows)
        return self._blocks[key]


class OrderedBlock:
    """A symmetric positive definite sub-matrix A[rows][:, rows] of the pattern, factorised each step
    by QDLDL (``qdldl.Solver``: LDL^T in an approximate-minimum-degree order found once, at the
    first factorisation; each later one is numeric only, on the same pattern).

    Args:
        ops: the mesh's operators (the pattern).
        rows: the block's nodes (the free nodes of a solve), in the order of ``solve``'s answer.

    Attributes:
        rows: those nodes.
        factorisations: how many times the block was factorised.
    """

    def __init__(self, ops: P1Operators, rows: np.ndarray):
        # The block's upper triangle (the factorisation reads only it), as positions in the
        # pattern's data array.
        index = sp.csr_matrix((np.arange(1, ops.nnz + 1, dtype=float), ops.indices, ops.indptr), shape=(ops.n, ops.n))
        upper = sp.triu(index[rows][:, rows], format="csc")
        upper.sort_indices()
        self.rows = np.asarray(rows)
        self._take = upper.data.astype(np.int64) - 1
        self._pattern = (upper.indices, upper.indptr)
        self._size = len(rows)
        self._solver = None
        self.factorisations = 0

    def factor(self, data) -> "BlockFactor":
        """The factors of the block of the matrix with pattern data ``data``; those of the block's
        previous factorisation can no longer solve."""
        a = sp.csc_matrix((data[self._take], *self._pattern), shape=(self._size, self._size))
        if self._solver is None:
            self._solver = qdldl.Solver(a, upper=True)
        else:
            self._solver.update(a, upper=True)
        self.factorisations += 1
        return BlockFactor(self, self.factorisations)


class BlockFactor:
    """The factors of one block: ``solve(rhs)`` takes a full-length right-hand side (only its block
    rows are read) and returns the solution on ``rows`` (in that order). Valid until the block is
    factorised again (the factors are refreshed in place)."""

    def __init__(self, block: OrderedBlock, factorisation: int):
        self.rows, self._block, self._factorisation = block.rows, block, factorisation

    def solve(self, rhs) -> np.ndarray:
        if self._block.factorisations != self._factorisation:
            raise RuntimeError("BlockFactor.solve: the block was factorised again since these factors were made")
        return self._block._solver.solve(np.ascontiguousarray(rhs[self.rows], dtype=float))
