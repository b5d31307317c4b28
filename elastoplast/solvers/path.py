"""Loading paths: Prandtl-Reuss' law by backward Euler, one certified problem per step.

A path ``F_1, F_2, ...`` (any order: loading, unloading, reloading) is solved
step by step from the unloaded state. Step n + 1 is Hencky's problem (2.1) with
the quadratic centred at the state ``(sigma_n, xi_n)`` and the obstacle shifted by
the last displacement (docs/evolution.md): :meth:`Discretization.step` builds it
on the same operators, every method of :data:`~elastoplast.solvers.registry.METHODS`
solves it (their return mappings read the state), and the answer of each step
is judged by the same KKT certificate, with the step's return mapping R_n, the
equilibrium against ``F_{n+1}`` and the contact conditions on the total gap.

The steps are part of the problem: there is no hidden sub-stepping, so two
codes agree on a path only if they take the same steps.
"""

from __future__ import annotations

import time
from functools import partial
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from elastoplast.certificate.solution import Solution, Status, small_strain_note
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization, check_path_scales
from elastoplast.fem.material import Prestate, return_mapping
from elastoplast.options import SolverOptions
from elastoplast.problem.load import check_forces
from elastoplast.solvers.registry import Method, check_solvable, get_method, given_options, refuse_depth_control

#: a step whose force is below the last one's by more than this share unloads
UNLOADING_SHARE = 1e-12
#: an element yields in a step when its dkappa exceeds the solver's tolerance times
#: this many strain scales (the yield strain sigma_y / E or the largest total strain,
#: whichever is larger): below, dkappa is the inaccuracy of a step that ends on the yield
#: surface at that tolerance. Measured on reloading to an earlier maximum (homogeneous
#: block, tol 1e-8, strains 7e-3): 1e-17 to 4e-18 for the conic methods and newton,
#: 6e-12 to 2.4e-11 for uzawa and uzawa-fast; real yielding there is 2.5e-3.
YIELD_STRAIN_SHARE = 10.0
#: methods whose runs start from a given point, and the option or argument that takes it
WARM_STARTS = {"newton": "warm_start", "uzawa": "initial", "uzawa-fast": "initial"}


@dataclass(frozen=True)
class PathStep:
    """One step of a loading path.

    ``solution`` is the step problem's certified answer: its ``u`` is the step's
    displacement increment, ``sigma``/``xi`` the stresses after the step and
    ``U`` the rigid body's total displacement; ``u`` here is the total nodal
    displacement. ``kappa`` is the accumulated equivalent plastic strain per
    element and ``dkappa`` its increment in this step (from the step's return
    mapping at the answer's displacement). ``plastic_work`` is
    ``sum_T |T| sigma : dp`` with ``dp = d eps - A (sigma - sigma_n)`` from the
    answer itself (at the exact solution it equals
    ``sum_T |T| (sigma_y + xi) dkappa >= 0``). ``yielding``: the elements whose
    ``dkappa`` exceeds the round-off threshold (:data:`YIELD_STRAIN_SHARE`);
    ``unloading``: the force fell; ``reverse_yield``: elements that yielded in
    an unloading step.
    """

    index: int
    force: float
    solution: Solution
    u: np.ndarray
    kappa: np.ndarray
    dkappa: np.ndarray
    plastic_work: float
    yielding: int
    unloading: bool
    reverse_yield: int
    warm_started: bool

    @property
    def U(self) -> float:
        return self.solution.U

    @property
    def status(self) -> Status:
        return self.solution.status

    @property
    def converged(self) -> bool:
        return self.solution.converged

    def summary(self, disc: Discretization) -> dict[str, Any]:
        """The step's entry of ``summary.json``'s ``"path"`` list."""
        sol = self.solution
        plastic = self.kappa > 0.0
        return {
            "step": self.index,
            "force": self.force,
            "U": float(sol.U),
            "status": sol.status.value,
            "kkt_worst": float(sol.kkt.worst),
            "plastic_volume_fraction": float(disc.volumes[plastic].sum() / disc.volumes.sum()),
            "yielding_elements": self.yielding,
            "plastic_work": float(self.plastic_work),
            "max_dkappa": float(self.dkappa.max(initial=0.0)),
            "max_kappa": float(self.kappa.max(initial=0.0)),
            "unloading": self.unloading,
            "reverse_yield": self.reverse_yield,
            "iterations": int(sol.iterations),
            "time_s": float(sol.time_s),
            "warm_started": self.warm_started,
        }


@dataclass(frozen=True)
class PathResult:
    """The steps of a path in order, and how they were obtained."""

    method: str
    forces: tuple[float, ...]  # the path's loads: forces, or the prescribed displacements under depth control
    steps: list[PathStep] = field(default_factory=list)
    time_s: float = 0.0
    control: str = "force"  # "displacement" for a depth path (ep.solve_depth_path)
    #: why the path stopped before its end with every step run converged ("" if it did not)
    stopped: str = ""

    @property
    def converged(self) -> bool:
        """Every step converged (and the path was run to its end)."""
        return len(self.steps) == len(self.forces) and all(s.converged for s in self.steps)

    @property
    def U(self) -> np.ndarray:
        return np.array([s.U for s in self.steps])

    def summary(self, disc: Discretization) -> list[dict[str, Any]]:
        return [s.summary(disc) for s in self.steps]

    def residual_imprint(self) -> float | None:
        """U at the end of the last unloading (the last run of steps whose force
        falls): the residual imprint's depth as the force goes to 0+; None when the
        path never unloads."""
        last: list[PathStep] = []
        for i, s in enumerate(self.steps):
            if s.unloading:
                last = (last if i > 0 and self.steps[i - 1].unloading else []) + [s]
        return float(last[-1].U) if last else None


def check_path(forces: Any, field_name: str = "load.path") -> tuple[float, ...]:
    """The forces of a path as floats, or an InputError naming ``field_name``: the
    rules of a problem file's ``load.path`` (:func:`~elastoplast.problem.load.check_forces`)."""
    return check_forces(forces, field_name)


def _guess(prev: PathStep | None, before: PathStep | None, force: float) -> Solution | None:
    """A start for the next step: the last increment scaled to the next force
    step (its direction is the likeliest), with U and the contact forces
    likewise; None on the first step or when the last step did not converge."""
    if prev is None or not prev.converged:
        return None
    f_prev = prev.force
    f_before = 0.0 if before is None else before.force
    ratio = 0.0 if f_prev == f_before else (force - f_prev) / (f_prev - f_before)
    ratio = float(np.clip(ratio, -2.0, 2.0))
    sol = prev.solution
    dU = sol.U - (0.0 if before is None else before.U)
    return replace(sol, u=ratio * sol.u, U=sol.U + ratio * dU, contact_force=sol.contact_force * (force / f_prev))


def run_from(disc: Discretization, m: Method, options: SolverOptions, start: Solution | None) -> Solution:
    """``disc`` solved by ``m``, from ``start`` where the method takes one (:data:`WARM_STARTS`;
    a path's step, or a solve at a nearby force)."""
    check_solvable(disc, m.name, options)
    takes = WARM_STARTS.get(m.name) if start is not None else None
    if takes == "warm_start":  # newton's argument
        from elastoplast.solvers.newton import solve_newton

        return solve_newton(disc, options, warm_start=start)
    return m.run(disc, options if takes is None else replace(options, **{takes: start}))


def solve_path(disc: Discretization, forces: Sequence[float], method: str = "conic", *,
               warm_start: bool = True, options: SolverOptions | None = None, callback=None,
               **values: Any) -> PathResult:
    """Solve the loading path ``forces`` (one backward-Euler step each, from the
    unloaded state) on ``disc`` with ``method``.

    Every step goes through the same KKT certificate; a step that does not
    converge ends the path there (its state would be no start for the next
    one), so ``result.steps`` may be shorter than ``forces``. ``warm_start``: the
    iterative methods (newton, uzawa, uzawa-fast) start each step from the last
    increment scaled to the next force step; the conic methods (interior points)
    always start cold. ``callback(step)`` is called after each step. ``time_limit``
    bounds the whole path: each step is given what is left, and when nothing is the
    path stops (``result.stopped`` says why; its status is ``time_limit``).
    Options are given as for :func:`~elastoplast.solvers.registry.solve`.
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    refuse_depth_control(disc, "ep.solve_path")
    if disc.state is not None:
        raise InputError("disc", "is already a step of a path: give the problem's discretisation (ep.discretize)")
    forces = check_path(forces, "forces")
    check_path_scales(disc, forces, "forces")
    m_run = get_method(method)
    name = m_run.name
    opts = given_options(method, options, values)
    if getattr(opts, "load_steps", 1) != 1:
        raise InputError("load_steps", f"is {opts.load_steps}: a path takes no hidden sub-steps (they would change "
                                       "the answer of Prandtl-Reuss' law); put the intermediate forces in the path")

    def step_solve(make_step, force: float, prev: PathStep | None, before: PathStep | None,
                   step_opts: SolverOptions) -> tuple[Solution, float, bool]:
        start = _guess(prev, before, force) if warm_start else None
        return run_from(make_step(force), m_run, step_opts, start), force, start is not None and name in WARM_STARTS

    return run_path(disc, forces, name, opts, step_solve, callback)


def run_path(disc: Discretization, loads: Sequence[float], name: str, opts: SolverOptions, step_solve,
             callback=None) -> PathResult:
    """The steps of a path from the unloaded state: ``step_solve(make_step, load, prev,
    before, step_opts) -> (solution, force, warm_started)`` solves one step
    (``make_step(F)`` is the step's discretisation at the force F; ``load`` a force, or
    a displacement under depth control; ``step_opts`` the options with what is left of
    the path's ``time_limit``), then the state is advanced as :func:`solve_path`
    documents."""
    t0 = time.perf_counter()
    forces = tuple(loads)
    m, n_el = disc.material, disc.n_elements
    yield_strain = m.yield_stress / m.E
    state = Prestate.of(m, np.zeros((n_el, disc.k)), np.zeros(n_el))
    u_free, kappa = np.zeros(disc.n_free), np.zeros(n_el)
    result = PathResult(name, forces)
    prev = before = None
    limit, stopped = opts.time_limit, ""
    for i, load in enumerate(forces):
        if limit is not None:  # the limit bounds the whole path: each step gets what is left
            left = limit - (time.perf_counter() - t0)
            if left <= 0:
                stopped = (f"the time limit of {limit:g} s ran out after {i} of {len(forces)} steps "
                           "(it bounds the whole path)")
                break
            step_opts = replace(opts, time_limit=left)
        else:
            step_opts = opts
        sol, force, warm = step_solve(partial(disc.step, state=state, u_free=u_free), load, prev, before, step_opts)
        du = disc.free_displacement(sol.u)
        d_eps = disc.strain(du)
        beyond = small_strain_note(disc, u_free + du)  # the total strain, not the increment's
        if sol.converged and beyond:
            sol = replace(sol, status=Status.FAILED, message=f"{sol.message}; {beyond}")
        _, _, dkappa = return_mapping(m, d_eps, state)
        dp = d_eps - (sol.sigma - state.sigma) @ m.compliance(disc.dim)
        work = float(disc.volumes @ np.einsum("ei,ei->e", sol.sigma, dp))
        unloading = prev is not None and force < prev.force * (1.0 - UNLOADING_SHARE)
        u_free = u_free + du
        kappa = kappa + dkappa
        strain = max(yield_strain, float(np.abs(disc.strain(u_free)).max(initial=0.0)))
        yielding = int(np.count_nonzero(dkappa > YIELD_STRAIN_SHARE * opts.tol * strain))
        step = PathStep(index=i + 1, force=force, solution=sol, u=disc.full_displacement(u_free), kappa=kappa,
                        dkappa=dkappa, plastic_work=work, yielding=yielding, unloading=unloading,
                        reverse_yield=yielding if unloading else 0,
                        warm_started=warm)
        result.steps.append(step)
        if callback is not None:
            callback(step)
        if not sol.converged:
            break
        state = Prestate.of(m, sol.sigma, sol.xi, max(state.displacement, np.abs(u_free).max(initial=0.0), abs(sol.U)))
        before, prev = prev, step
    return replace(result, time_s=time.perf_counter() - t0, stopped=stopped)
