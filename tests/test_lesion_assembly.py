"""The lesion FEM's assembly on a fixed pattern (issue 48) against scikit-fem's ``asm`` of the same forms,
its block solves against a direct solve of the sliced matrix, and the generated tables keyed by every
module of the FEM."""

import importlib

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from skfem import CellBasis, ElementTriP1, asm

from ballchain.drake_models import lesion_assembly as la
from ballchain.drake_models import lesion_dwell as ld
from ballchain.drake_models import lesion_fem as fem
from ballchain.drake_models import lesion_surrogate as ls

RTOL = 1e-12


@pytest.fixture(scope="module")
def setup():
    am = fem.build_mesh(fem.ball_chain_tip(1e-3), h=0.3e-3)
    basis = CellBasis(am.mesh, ElementTriP1())
    return am, basis, la.P1Operators(basis), np.random.default_rng(7)


def _relative(a, b) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_diffusion_matches_skfem_asm(setup):
    am, basis, ops, rng = setup
    # A coefficient varying per quadrature point, with zeros (the electrode) and a jump of decades.
    coef = rng.uniform(0.1, 2.0, size=ops.shape_qp) * np.where(rng.random(ops.shape_qp[0]) < 0.1, 1e-2, 1.0)[:, None]
    coef[am.domain == fem.ELECTRODE] = 0.0
    ref = asm(la.diffusion_form, basis, coef=coef).toarray()
    new = ops.matrix(ops.diffusion(coef)).toarray()
    assert _relative(new, ref) < RTOL
    # The pattern holds every nonzero of the reference (nothing assembled outside it).
    assert np.all(ops.matrix(np.ones(ops.nnz)).toarray()[ref != 0] == 1.0)


def test_source_interpolation_and_gradient_match_skfem(setup):
    am, basis, ops, rng = setup
    q = rng.uniform(-1.0, 3.0, size=ops.shape_qp)
    assert _relative(ops.source(q), asm(la.source_form, basis, q=q)) < RTOL
    u = rng.uniform(-1.0, 1.0, size=ops.n)
    field = basis.interpolate(u)
    assert _relative(ops.at_quadrature(u), np.asarray(field)) < RTOL
    g_r, g_z = ops.gradient(u)
    assert _relative(np.c_[g_r, g_z], np.c_[field.grad[0][:, 0], field.grad[1][:, 0]]) < RTOL


def test_data_of_places_a_matrix_and_refuses_entries_outside_the_pattern(setup):
    am, basis, ops, rng = setup
    mass = asm(la.mass_form, basis, coef=np.ones(ops.shape_qp))
    assert _relative(ops.matrix(ops.data_of(mass)).toarray(), mass.toarray()) < RTOL
    far = sp.coo_matrix(([1.0], ([0], [ops.n - 1])), shape=(ops.n, ops.n))  # two nodes of no common element
    assert ops.matrix(np.ones(ops.nnz))[0, ops.n - 1] == 0.0
    with pytest.raises(ValueError, match="pattern"):
        ops.data_of(far)


def test_block_solve_matches_a_direct_solve_of_the_sliced_matrix(setup):
    am, basis, ops, rng = setup
    coef = rng.uniform(0.5, 1.5, size=ops.shape_qp)
    data = ops.diffusion(coef)
    data[ops.diagonal] += rng.uniform(1.0, 2.0, size=ops.n) * 1e-9  # a mass / dt term
    A = ops.matrix(data)
    free = np.setdiff1d(np.arange(ops.n), am.ground_nodes)
    block = ops.block(free)
    assert ops.block(free) is block  # built once per row set
    np.testing.assert_array_equal(block.rows, free)
    b = rng.uniform(-1.0, 1.0, size=ops.n)
    x = np.zeros(ops.n)
    first = block.factor(data)
    x[block.rows] = first.solve(b)
    ref = spla.spsolve(A[free][:, free].tocsc(), b[free])
    assert _relative(x[free], ref) < 1e-10
    assert np.abs(A[free] @ x - b[free]).max() < 1e-10 * np.abs(b).max()
    # Another step's matrix on the same pattern (the symbolic analysis reused): its own solution;
    # the first step's factors are refreshed in place, so they refuse to solve.
    data2 = ops.diffusion(rng.uniform(0.5, 1.5, size=ops.shape_qp))
    data2[ops.diagonal] += 1e-9
    second = block.factor(data2)
    x2 = second.solve(b)
    assert _relative(x2, spla.spsolve(ops.matrix(data2)[free][:, free].tocsc(), b[free])) < 1e-10
    assert _relative(x2, ref) > 1e-3 and block.factorisations == 2
    with pytest.raises(RuntimeError, match="factorised again"):
        first.solve(b)


@pytest.mark.parametrize("module", ["lesion_mesh", "lesion_assembly", "lesion_fem"])
def test_the_generated_tables_are_keyed_by_every_module_of_the_fem(module, monkeypatch, tmp_path):
    """The FEM lives in three modules (mesh, assembly, model): a change to any of them makes new
    lesion tables (``lesion_surrogate.TableSpec.key``, ``lesion_dwell.DwellTableSpec.key``)."""
    target = importlib.import_module(f"ballchain.drake_models.{module}")
    before = ls.TableSpec().key(), ld.SHIPPED_SPECS[0].key()
    altered = tmp_path / f"{module}.py"
    altered.write_bytes(open(target.__file__, "rb").read() + b"\n# changed\n")
    monkeypatch.setattr(target, "__file__", str(altered))
    after = ls.TableSpec().key(), ld.SHIPPED_SPECS[0].key()
    assert before[0] != after[0] and before[1] != after[1]
