"""External solvers on the package's own instances (elastoplast/io/external.py), each
answer judged by the KKT certificate before it counts.

Tolerances, per solver, at the solver's own default settings (measured on the 2D
cylinder of 1600 triangles, the 3D quarter box of 1080 tetrahedra and three more
meshes, see docs/methods.md, "External solvers"):

* Clarabel (interior point, gap 1e-8): worst certified residual 3e-6..2e-5, U within
  1e-7 of the conic method's. Its dual displacements carry the error of a gap of 1e-8
  into the worst element's strains: tolerance 1e-4 (the method's default ``tol``).
* SCS (first-order splitting, eps 1e-4): residuals 1e-6..4e-4, U within 2e-5. Its
  residuals are of the size of eps relative to the data, and where it stops varies with
  the sparsity pattern: tolerance 1e-2 (its default ``tol``).
* ECOS (interior point, tolerances 1e-8, the energy in a cone): residuals 2e-5..2.4e-4,
  U within 2e-4: the whole displacement field is off by that, not one element:
  tolerance 1e-3 (its default ``tol``).
* OSQP on the elastic QP: polishing on the contact set lands on the QP's solution to
  rounding (7e-14): U to 1e-9 of Clarabel's polished answer.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import build, cylinder_dict

import elastoplast as ep
from elastoplast.errors import InputError
from elastoplast.io.export import export
from elastoplast.io.export_files import load_npz
from elastoplast.io.external import (
    YIELDS,
    ClarabelExportOptions,
    ECOSExportOptions,
    SCSExportOptions,
    exported_stress_form,
    run_clarabel_export,
    run_ecos_export,
    run_osqp_elastic,
    run_scs_export,
)

#: (run, options class, the tolerance the answer is certified at and U is compared to)
SOLVERS = {
    "clarabel-export": (run_clarabel_export, ClarabelExportOptions, 1e-4),
    "scs-export": (run_scs_export, SCSExportOptions, 1e-2),
    "ecos-export": (run_ecos_export, ECOSExportOptions, 1e-3),
}


def relative(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def test_in_memory_program_is_the_exported_file(cylinder_disc, tmp_path):
    """The external methods solve exactly what ``export`` writes (npz, quadratic energy)."""
    export(cylinder_disc, tmp_path / "s.npz", "npz", "S", energy="quadratic")
    data = load_npz(tmp_path / "s.npz")
    prog = exported_stress_form(cylinder_disc, "quadratic")
    for name in ("A", "P"):
        assert (abs(data[name] - getattr(prog, name)) > 0).nnz == 0
    np.testing.assert_array_equal(data["q"], prog.q)
    np.testing.assert_array_equal(data["b"], prog.b)
    assert data["cones"] == {"z": prog.zero, "l": prog.nonnegative, "q": prog.second_order}


@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_external_solver_certified_on_cylinder(name, cylinder_disc, cylinder_conic):
    run, options, tol = SOLVERS[name]
    assert options().tol == tol  # the default tol is the one justified above
    sol = run(cylinder_disc, options())
    assert sol.converged, sol.message
    assert sol.kkt.worst <= tol
    assert relative(sol.U, cylinder_conic.U) <= tol
    assert sol.method == name and "certified KKT residual" in sol.message


def test_clarabel_export_certified_in_3d(quarter_disc, quarter_conic):
    sol = run_clarabel_export(quarter_disc, ClarabelExportOptions(energy="cone"))
    assert sol.converged, sol.message
    assert sol.kkt.worst <= 1e-4
    assert relative(sol.U, quarter_conic.U) <= 1e-4


@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_two_iterations_are_not_converged(name, cylinder_disc):
    """Negative control: the solver's limit, never CONVERGED; its own word in the message."""
    run, options, _ = SOLVERS[name]
    sol = run(cylinder_disc, options(max_iter=2))
    assert sol.status is ep.Status.MAX_ITERATIONS, sol.message
    assert sol.kkt.worst > options().tol
    assert "after 2 iterations" in sol.message


def test_the_certificate_not_the_solver_decides(cylinder_disc):
    """Clarabel says Solved; at the tightest tol the certificate says no."""
    sol = run_clarabel_export(cylinder_disc, ClarabelExportOptions(tol=1e-13))
    assert sol.status is ep.Status.FAILED
    assert "Clarabel: Solved" in sol.message and "above tol" in sol.message


def test_ecos_time_limit_is_checked_on_return(cylinder_disc):
    """ECOS has no clock: a run past time_limit whose answer is not certified ends as
    time_limit (checked when ECOS returns); a certified one stays converged."""
    late = run_ecos_export(cylinder_disc, ECOSExportOptions(time_limit=1e-9, tol=1e-13))
    assert late.status is ep.Status.TIME_LIMIT and "past time_limit" in late.message
    assert run_ecos_export(cylinder_disc, ECOSExportOptions(time_limit=1e-9)).converged


def test_osqp_elastic_matches_conic_below_yield():
    disc = build(cylinder_dict(yield_stress=1e6))
    ref = ep.solve(disc, "conic")
    sol = run_osqp_elastic(disc)
    assert sol.converged, sol.message
    assert sol.kkt.worst <= 1e-6
    assert relative(sol.U, ref.U) <= 1e-6
    assert not sol.plastic.any()


def test_osqp_elastic_refuses_an_answer_that_yields(cylinder_disc):
    sol = run_osqp_elastic(cylinder_disc)
    assert sol.status is ep.Status.FAILED
    assert sol.message.startswith(YIELDS) and "material.yield_stress" in sol.message


def test_uzawa_with_osqp_contact_step(cylinder_disc):
    default = ep.solve(cylinder_disc, "uzawa", tol=1e-9)
    osqp = ep.solve(cylinder_disc, "uzawa", tol=1e-9, contact_qp="osqp")
    assert default.converged and osqp.converged, osqp.message
    assert "OSQP" in osqp.message
    assert relative(osqp.U, default.U) <= 1e-8


def test_osqp_contact_step_refused_on_the_iterative_path(cylinder_disc):
    with pytest.raises(InputError) as err:
        ep.solve(cylinder_disc, "uzawa", contact_qp="osqp", factorization="amg")
    assert err.value.field == "contact_qp"


@pytest.mark.parametrize("name", ["clarabel-export", "scs-export", "ecos-export", "osqp-elastic"])
def test_external_methods_are_registered_by_name(name, cylinder_disc):
    """The package declares them in the entry-point group elastoplast.methods (pyproject.toml),
    the way an outside method is registered: found by name, with their own options."""
    from elastoplast.solvers.registry import get_method

    method = get_method(name)
    assert method.name == name and method.options.__name__.endswith("Options")
    if name == "clarabel-export":
        sol = ep.solve(cylinder_disc, name)
        assert sol.method == name and sol.converged, sol.message
