"""Static solves: linear superposition, and Newton with line search and load stepping.

Equilibrium r(u) = f_int(u) - f_ext = 0 on the free DOFs, u = g on the prescribed ones.
Newton correction: K_II du_I = -(r_I + K_ID du_D), du_D = g - u_D (so the first iteration of a
load step is the tangent predictor that carries the guide increment into the interior).
K_II is solved by conjugate gradients preconditioned with the last PARDISO factorisation (above
AMG_MIN_DOFS unknowns, the last AMG hierarchy); a new one is made only when CG needs more than
its `max_cg` iterations (the old one has drifted).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from scipy.sparse.linalg import LinearOperator, cg

from . import elasticity as el
from .assembly import apply_matrix, assemble_matrix, assemble_vector
from .linsolve import Factor, factorise, rigid_body_modes
from .problem import Problem

log = logging.getLogger(__name__)

CG_RTOL = 1e-2  # inexact Newton: the outer iteration removes what CG leaves


class ConvergenceError(RuntimeError):
    """Newton did not converge or an element inverted (det F <= 0); nothing is written."""


@dataclass
class Stats:
    iterations: int = 0
    factorizations: int = 0
    cg_iterations: int = 0
    residual: float = 0.0  # final ||r_I|| / ||reactions||
    min_det_f: float = 1.0
    seconds: float = 0.0
    halvings: int = 0

    def record(self) -> dict:
        """The fields a snapshot file stores."""
        return {
            "newton_iterations": self.iterations,
            "factorizations": self.factorizations,
            "cg_iterations": self.cg_iterations,
            "residual": self.residual,
            "min_det_f": self.min_det_f,
            "seconds": self.seconds,
        }


@dataclass
class PathState:
    """What a displacement path carries from one converged step to the next."""

    u: np.ndarray
    d_mm: float = 0.0
    history: list = field(default_factory=list)  # up to two earlier (d, u) for the path predictor
    factor: Factor | None = None


class Eval(NamedTuple):
    """What one pass over the quadrature points gives: residual (n_dofs,), min det F, potential, and
    what the tangent needs (F^-1, J), so the tangent is built only when a correction follows."""

    r: np.ndarray | None
    min_j: float
    pi: float
    Finv: np.ndarray | None = None
    J: np.ndarray | None = None


def _evaluate(p: Problem, u: np.ndarray) -> Eval:
    """Residual r = f_int(u) - f_ext, min det F and the potential Pi(u); r is None if det F <= 0."""
    H = el.displacement_gradient(p.G, p.element_displacement(u))
    work = p.body_force @ u if p.body_force is not None else 0.0
    if p.nonlinear:
        P, Finv, J = el.neo_hookean_stress(H, p.mu, p.lam)
        min_j = float(J.min())
        if not min_j > 0:
            return Eval(None, min_j, np.inf)
        pi = el.neo_hookean_energy(H, J, p.W, p.mu, p.lam) - work
    else:
        P, min_j, Finv, J = el.linear_stress(H, p.mu, p.lam), 1.0, None, None
        pi = el.linear_energy(H, p.W, p.mu, p.lam) - work
    r = assemble_vector(p.pattern, el.internal_force(p.G, p.W, P))
    if p.body_force is not None:
        r -= p.body_force
    return Eval(r, min_j, pi, Finv, J)


def _tangent(p: Problem, ev: Eval) -> np.ndarray:
    if p.nonlinear:
        return el.neo_hookean_tangent(p.G, p.W, ev.Finv, ev.J, p.mu, p.lam)
    return el.linear_stiffness(p.G, p.W, p.mu, p.lam)


def _solve_linearised(p: Problem, state: PathState, K, rhs, stats: Stats) -> np.ndarray:
    """K du = rhs by CG preconditioned with the path's factorisation (or AMG hierarchy above
    AMG_MIN_DOFS); refactorise when CG needs more than the solver's max_cg iterations (it drifted)."""
    if state.factor is not None:
        M = LinearOperator(K.shape, matvec=state.factor.precondition, dtype=np.float64)
        count = [0]
        du, info = cg(K, rhs, rtol=CG_RTOL, maxiter=state.factor.max_cg, M=M,
                      callback=lambda _: count.__setitem__(0, count[0] + 1))
        stats.cg_iterations += count[0]
        if info == 0:
            return du
    if state.factor is not None:
        state.factor = state.factor.refactor(K)
    else:
        state.factor = factorise(K, rigid_body_modes(p.mesh.nodes)[p.free], rtol=CG_RTOL)
    stats.factorizations += 1
    try:
        return state.factor.solve(rhs)
    except np.linalg.LinAlgError as exc:  # AMG-CG on a tangent that lost definiteness
        raise ConvergenceError(str(exc)) from None


def newton_step(problem: Problem, state: PathState, g: np.ndarray, stats: Stats) -> np.ndarray:
    """Converge to equilibrium with u_D = g, starting from state.u; raise ConvergenceError."""
    p, cfg = problem, problem.scene.solver
    free = p.free
    u = state.u.copy()
    ev = _evaluate(p, u)
    if ev.r is None:
        raise ConvergenceError(f"start state has det F = {ev.min_j:.3g} <= 0")
    for it in range(cfg.max_iterations + 1):
        du_d = g - u
        du_d[free] = 0.0
        reactions = np.linalg.norm(np.delete(ev.r, free)) + (np.linalg.norm(p.body_force) if p.body_force is not None else 0)
        res = np.linalg.norm(ev.r[free]) / max(reactions, 1e-30)
        stats.residual, stats.min_det_f = res, ev.min_j
        prescribed_done = not np.any(du_d)
        if prescribed_done and (res <= cfg.rtol or np.linalg.norm(ev.r[free]) < 1e-13):
            stats.iterations += it
            return u
        if it == cfg.max_iterations:
            break
        Ke = _tangent(p, ev)
        rhs = -(ev.r + apply_matrix(p.pattern, Ke, du_d))[free]
        step = du_d
        step[free] = _solve_linearised(p, state, assemble_matrix(p.pattern, Ke), rhs, stats)
        u, ev = _line_search(p, u, step, ev, prescribed_done)
    raise ConvergenceError(
        f"Newton did not converge in {cfg.max_iterations} iterations (relative residual {stats.residual:.2e})"
    )


def _line_search(p: Problem, u, step, ev: Eval, prescribed_done: bool):
    """Backtrack alpha = 1, 1/2, ... until det F > 0 everywhere and, once u_D = g, Armijo holds.

    Equilibrium minimises the potential Pi, so with the constraints met the Newton direction must
    lower Pi (Armijo, slope r . du); this guards against steps past a limit point, where the
    residual norm alone can mislead. While a guide increment is still being applied, any admissible
    (det F > 0) step is taken.
    """
    alpha, slope = 1.0, float(ev.r[p.free] @ step[p.free])
    for _ in range(10):
        trial = u + alpha * step
        new = _evaluate(p, trial)
        armijo = new.pi <= ev.pi + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * abs(ev.pi)
        if new.r is not None and (not prescribed_done or armijo):
            return trial, new
        alpha *= 0.5
    raise ConvergenceError("line search found no step with det F > 0 that lowers the potential energy")


def _predict(state: PathState, d_mm: float) -> np.ndarray:
    """Extrapolate along the path (Lagrange, through up to three converged states)."""
    ds = [d for d, _ in state.history] + [state.d_mm]
    us = [u for _, u in state.history] + [state.u]
    guess = np.zeros_like(state.u)
    for i, (di, ui) in enumerate(zip(ds, us)):
        weight = np.prod([(d_mm - dj) / (di - dj) for j, dj in enumerate(ds) if j != i])
        guess += weight * ui
    return guess


def advance(problem: Problem, state: PathState, d_mm: float, angle_deg: float, stats: Stats, depth: int = 0) -> None:
    """Move the path state to guide displacement d_mm, halving the load step on failure."""
    g = problem.dirichlet(d_mm, angle_deg)
    guess = _predict(state, d_mm)
    try:
        trial = PathState(guess, state.d_mm, state.history, state.factor)
        if problem.nonlinear and problem.min_jacobian(guess) <= 0:
            trial.u = state.u
        u = newton_step(problem, trial, g, stats)
    except ConvergenceError:
        state.factor = trial.factor
        if depth >= problem.scene.solver.max_halvings:
            raise
        stats.halvings += 1
        log.info("halving load step %.4g -> %.4g mm", state.d_mm, d_mm)
        advance(problem, state, 0.5 * (state.d_mm + d_mm), angle_deg, stats, depth + 1)
        advance(problem, state, d_mm, angle_deg, stats, depth + 1)
        return
    state.factor = trial.factor
    state.history = [*state.history[-1:], (state.d_mm, state.u)]
    state.u, state.d_mm = u, d_mm


def initial_state(problem: Problem) -> PathState:
    """Reference state, or the gravity-loaded state when gravity is on (loaded in 4 steps)."""
    state = PathState(np.zeros(problem.n_dofs))
    if problem.body_force is None:
        return state
    full = problem.body_force
    for s in (0.25, 0.5, 0.75, 1.0):
        scaled = replace(problem, body_force=s * full)
        state.u = newton_step(scaled, state, np.zeros(problem.n_dofs), Stats())
    state.history = []
    return state


def solve_path(problem: Problem, displacements_mm, angle_deg: float, state: PathState | None = None):
    """Yield (d_mm, u (n_nodes, 3), Stats) for increasing guide displacements at one angle."""
    state = state or initial_state(problem)
    max_step = problem.scene.solver.max_step_mm
    for d in displacements_mm:
        stats, t0 = Stats(), time.perf_counter()
        n_sub = max(1, int(np.ceil(abs(d - state.d_mm) / max_step - 1e-9)))
        for target in np.linspace(state.d_mm, d, n_sub + 1)[1:]:
            last = state.d_mm
            try:
                advance(problem, state, float(target), angle_deg, stats)
            except ConvergenceError as exc:
                raise ConvergenceError(
                    f"no equilibrium found for guide displacement {target:.4g} mm at beta {angle_deg:g} deg "
                    f"(last converged: {last:.4g} mm; load step halved {problem.scene.solver.max_halvings} times): {exc}"
                ) from None
            log.info("%.4g mm at beta %g deg: %d Newton iterations, %d CG, %d factorisations, %.1f s so far",
                     target, angle_deg, stats.iterations, stats.cg_iterations, stats.factorizations, time.perf_counter() - t0)
        stats.seconds = time.perf_counter() - t0
        yield float(d), state.u.reshape(-1, 3).copy(), stats


def linear_modes(problem: Problem):
    """Unit-displacement fields for the linear model: u(d, beta) = u_0 + d (cos b U_axis + sin b U_perp).

    One factorisation of K_II serves every case (superposition); u_0 is the gravity sag or zero.
    """
    p = problem
    Ke = el.linear_stiffness(p.G, p.W, p.mu, p.lam)
    factor = factorise(assemble_matrix(p.pattern, Ke), near_nullspace=rigid_body_modes(p.mesh.nodes)[p.free])
    fields = []
    for beta in (0.0, 90.0):
        g = p.dirichlet(1.0, beta)
        u = g.copy()
        u[p.free] = factor.solve(-apply_matrix(p.pattern, Ke, g)[p.free])
        fields.append(u)
    u0 = np.zeros(p.n_dofs)
    if p.body_force is not None:
        u0[p.free] = factor.solve(p.body_force[p.free])
    return u0, fields[0], fields[1]


def solve_case(problem: Problem, displacement_mm: float, angle_deg: float, step_mm: float | None = None):
    """One case: (u (n_nodes, 3), Stats). Nonlinear cases are load-stepped from zero in steps <= step_mm."""
    t0 = time.perf_counter()
    if not problem.nonlinear:
        u0, ua, ub = linear_modes(problem)
        b = np.deg2rad(angle_deg)
        u = u0 + displacement_mm * (np.cos(b) * ua + np.sin(b) * ub)
        return u.reshape(-1, 3), Stats(factorizations=1, seconds=time.perf_counter() - t0)
    if step_mm is not None:
        problem = replace(problem, scene=problem.scene.model_copy(update={"solver": problem.scene.solver.model_copy(update={"max_step_mm": step_mm})}))
    total = Stats()
    u = np.zeros((len(problem.mesh.nodes), 3))
    for _, u, stats in solve_path(problem, [displacement_mm], angle_deg):
        for name in ("iterations", "factorizations", "cg_iterations", "halvings"):
            setattr(total, name, getattr(total, name) + getattr(stats, name))
        total.residual, total.min_det_f = stats.residual, stats.min_det_f
    total.seconds = time.perf_counter() - t0
    return u, total
