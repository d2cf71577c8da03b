"""Newton's method with a backtracking line search for static equilibrium.

Equilibrium r(u) = f_int(u) - f_ext (+ the guide tip's contact forces, contact.py) = 0 on the free
DOFs, u = g on the prescribed ones.
Newton correction: K_II du_I = -(r_I + K_ID du_D), du_D = g - u_D (so the first iteration after
a change of g is the tangent predictor that carries the guide increment into the interior).
K_II is solved by conjugate gradients preconditioned with the last PARDISO factorisation (above
AMG_MIN_DOFS unknowns, the last AMG hierarchy); a new one is made only when CG needs more than
its `max_cg` iterations (the old one has drifted).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from scipy.sparse.linalg import LinearOperator, cg

from fem_offline.fe import contact as ct
from fem_offline.fe import elasticity as el
from fem_offline.fe import mixed
from fem_offline.fe.assembly import apply_matrix, assemble_matrix, assemble_vector
from fem_offline.fe.linsolve import Factor, factorise, rigid_body_modes
from fem_offline.fe.problem import Problem

CG_RTOL = 1e-2  # inexact Newton: the outer iteration removes what CG leaves
# Below this relative residual the tangent takes the contact's curvature term (contact.stiffness):
# the exact Hessian, so the last iterations converge quadratically instead of halving the residual
# each. Further out, where penetrations (and so pressures) are still far from equilibrium, the term
# made the tangent indefinite (contact.py).
EXACT_CONTACT_BELOW = 1e-2
# The tangent's PARDISO factors are float32 (linsolve.Factor, mixed.SaddleFactor): they only precondition CG
# to CG_RTOL, or give a correction the next Newton iteration corrects. Measured (`python -m studies profile-path`): see
# README and mixed.py. A superposable (linear, glued) problem keeps float64 ones: its one solve is the answer,
# exact to round-off.
SINGLE_FACTORS = True


@dataclass(frozen=True)
class Stats:
    """Solver work and the final state of one solve; a snapshot file stores `record()`."""

    iterations: int = 0
    factorizations: int = 0
    cg_iterations: int = 0
    residual: float = 0.0  # final ||r_I|| / ||reactions||
    min_det_f: float = 1.0
    seconds: float = 0.0
    halvings: int = 0
    contact_updates: int = 0  # augmented-Lagrangian multiplier updates (effects.guide_contact)
    penetration_mm: float = 0.0  # deepest penetration of the wall into the tip left in the solution

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


class ConvergenceError(RuntimeError):
    """Newton did not converge or an element inverted (det F <= 0); nothing is written.

    `stats` holds the work done up to the failure: a retry with a halved load step adds to it.
    """

    def __init__(self, message: str, stats: Stats | None = None):
        super().__init__(message)
        self.stats = stats if stats is not None else Stats()


class FactorCache:
    """The factorisation (or AMG hierarchy) that preconditions the next tangent solve of a path.

    Mutable on purpose: it is a cache of MKL memory behind a PARDISO handle, refactorised in place
    (`Factor.refactor`), and shared by reference along a path, so that a failed Newton attempt's
    fresh factorisation still serves the retry with a halved step.
    """

    def __init__(self, factor: Factor | None = None):
        self.factor = factor


class Eval(NamedTuple):
    """What one pass over the quadrature points gives: residual (n_dofs,), min det F, potential, and
    what the tangent needs (F^-1, J), so the tangent is built only when a correction follows."""

    r: np.ndarray | None
    min_j: float
    pi: float
    Finv: np.ndarray | None = None
    J: np.ndarray | None = None
    contact: ct.State | None = None
    pressure: np.ndarray | None = None  # Taylor-Hood: p at the quadrature points (n_tets, n_qp)


def residual(p: Problem, u: np.ndarray) -> Eval:
    """Residual r = f_int(u) - f_ext (n_dofs,), min det F and the potential Pi(u); r is None if det F <= 0."""
    H = el.displacement_gradient(p.G, p.element_displacement(u))
    work = p.body_force @ u if p.body_force is not None else 0.0
    if p.taylor_hood:
        return _residual_taylor_hood(p, u, H, work)
    if p.nonlinear:
        P, Finv, J = el.neo_hookean_stress(H, p.mu, p.lam, p.W if p.mean_dilatation else None)
        min_j = float(J.min())
        if not min_j > 0:
            return Eval(None, min_j, np.inf)
        pi = el.neo_hookean_energy(H, J, p.W, p.mu, p.lam, p.mean_dilatation) - work
    else:
        P, min_j, Finv, J = el.linear_stress(H, p.mu, p.lam, p.W if p.mean_dilatation else None), 1.0, None, None
        pi = el.linear_energy(H, p.W, p.mu, p.lam, p.mean_dilatation) - work
    r, pi, touch = _loads_and_contact(p, u, P, pi)
    return Eval(r, min_j, pi, Finv, J, touch)


def _loads_and_contact(p: Problem, u: np.ndarray, P: np.ndarray,
                       pi: float) -> tuple[np.ndarray, float, ct.State | None]:
    """r = f_int(P) - f_gravity + the tip's contact force, and Pi plus the contact energy."""
    r = assemble_vector(p.pattern, el.internal_force(p.G, p.W, P))
    if p.body_force is not None:
        r -= p.body_force
    touch = None
    if p.contact is not None:
        touch = ct.evaluate(p.contact, u, p.contact_load)
        r += ct.scatter(p.contact, touch.force, p.n_dofs)
        pi += touch.energy
    return r, pi, touch


def _residual_taylor_hood(p: Problem, u: np.ndarray, H: np.ndarray, work: float) -> Eval:
    """residual() for the Taylor-Hood element: the pressure projected from ln J (tr eps), then the stress (mixed.py)."""
    zero = np.zeros_like(p.lam)
    projected = {}

    def pressure(J):
        with np.errstate(invalid="ignore", divide="ignore"):
            projected["b"], _, projected["q"] = p.pressure.project(p.W, np.log(J))
        return projected["q"]

    if p.nonlinear:
        P, Finv, J = el.neo_hookean_stress(H, p.mu, zero, pressure=pressure)
        min_j = float(J.min())
        if not min_j > 0:
            return Eval(None, min_j, np.inf)
        b, q = projected["b"], projected["q"]
        pi = el.neo_hookean_energy(H, J, p.W, p.mu, zero) + 0.5 * b @ p.pressure.mass_factor.solve(b) - work
    else:
        b, _, q = p.pressure.project(p.W, np.trace(H, axis1=2, axis2=3))
        P, min_j, Finv, J = el.linear_stress(H, p.mu, zero, pressure=q), 1.0, None, None
        pi = el.linear_energy(H, p.W, p.mu, zero) + 0.5 * b @ p.pressure.mass_factor.solve(b) - work
    r, pi, touch = _loads_and_contact(p, u, P, pi)
    return Eval(r, min_j, pi, Finv, J, touch, q)


def _coupling(p: Problem, ev: Eval):
    """Taylor-Hood's G = db/du (all DOFs): int N_a dN_n/dx_i, spatial gradients under finite strain."""
    grad = p.G if ev.Finv is None else np.matmul(p.G, ev.Finv)
    return p.pressure.coupling(p.W, grad, p.n_dofs)


def _tangent(p: Problem, ev: Eval, exact_contact: bool = False) -> np.ndarray:
    if p.taylor_hood:
        zero = np.zeros_like(p.lam)
        if p.nonlinear:
            Ke = el.neo_hookean_tangent(p.G, p.W, ev.Finv, ev.J, p.mu, zero, pressure=ev.pressure)
        else:
            Ke = el.linear_stiffness(p.G, p.W, p.mu, zero)
    elif p.nonlinear:
        Ke = el.neo_hookean_tangent(p.G, p.W, ev.Finv, ev.J, p.mu, p.lam, p.mean_dilatation)
    else:
        Ke = el.linear_stiffness(p.G, p.W, p.mu, p.lam, p.mean_dilatation)
    if ev.contact is not None:
        ct.add_stiffness(p.contact, Ke, ev.contact, curvature=exact_contact)
    return Ke


def tangent_operator(p: Problem, u: np.ndarray) -> tuple[object, Eval]:
    """The exact tangent at u on the free DOFs (the Taylor-Hood reduced Hessian as a mixed.Tangent), and residual(u)."""
    ev = residual(p, u)
    if ev.r is None:
        raise ConvergenceError(f"det F = {ev.min_j:.3g} <= 0 at the state to linearise about")
    K = assemble_matrix(p.pattern, _tangent(p, ev, exact_contact=True))
    if p.taylor_hood:
        return mixed.Tangent(K, _coupling(p, ev)[:, p.free].tocsr(), p.pressure), ev
    return K, ev


def _preconditioned_cg(K, rhs, factor, stats: Stats) -> tuple[np.ndarray | None, Stats]:
    """K du = rhs by CG to CG_RTOL preconditioned with `factor`; None when it needs more than factor.max_cg."""
    M = LinearOperator(K.shape, matvec=factor.precondition, dtype=np.float64)
    count = [0]
    du, info = cg(K, rhs, rtol=CG_RTOL, maxiter=factor.max_cg, M=M,
                  callback=lambda _: count.__setitem__(0, count[0] + 1))
    return (du if info == 0 else None), replace(stats, cg_iterations=stats.cg_iterations + count[0])


def _solve_linearised(p: Problem, cache: FactorCache, K, rhs, stats: Stats) -> tuple[np.ndarray, Stats]:
    """K du = rhs by CG preconditioned with the cached factorisation (or AMG hierarchy above
    AMG_MIN_DOFS); refactorise when CG needs more than the solver's max_cg iterations (it drifted).

    Fresh float32 factors also go through CG on the float64 K: on an ill-conditioned tangent (a
    stiffness contrast of 1e4) their own solve can be too inexact to lower the energy. Where CG
    cannot converge with them either, the tangent is factorised in float64."""
    if cache.factor is not None:
        du, stats = _preconditioned_cg(K, rhs, cache.factor, stats)
        if du is not None:
            return du, stats
    if cache.factor is not None:
        cache.factor = cache.factor.refactor(K)
    elif isinstance(K, mixed.Tangent):
        cache.factor = K.factorise(float32=SINGLE_FACTORS)
    else:
        cache.factor = factorise(K, rigid_body_modes(p.mesh.nodes)[p.free], rtol=CG_RTOL,
                                 float32=SINGLE_FACTORS and not p.superposable)
    stats = replace(stats, factorizations=stats.factorizations + 1)
    if cache.factor.cg_first:
        du, stats = _preconditioned_cg(K, rhs, cache.factor, stats)
        if du is not None:
            return du, stats
        cache.factor = Factor(K)
        stats = replace(stats, factorizations=stats.factorizations + 1)
    try:
        return cache.factor.solve(rhs), stats
    except np.linalg.LinAlgError as exc:  # AMG-CG on a tangent that lost definiteness
        raise ConvergenceError(str(exc), stats) from None


def _relative_residual(p: Problem, r: np.ndarray) -> float:
    """||r_I|| / (||reactions|| + ||f_gravity||)."""
    reactions = np.linalg.norm(np.delete(r, p.free)) + (np.linalg.norm(p.body_force) if p.body_force is not None else 0)
    return np.linalg.norm(r[p.free]) / max(reactions, 1e-30)


def newton(problem: Problem, u: np.ndarray, g: np.ndarray, cache: FactorCache,
           stats: Stats = Stats()) -> tuple[np.ndarray, Stats]:
    """Converge from u (n_dofs,) to equilibrium with u_D = g; return it and stats + this solve's work.

    Raises ConvergenceError, carrying the work done, when it does not converge in max_iterations.
    """
    p, cfg = problem, problem.scene.solver
    free = p.free
    u = u.copy()
    ev = residual(p, u)
    if ev.r is None:
        raise ConvergenceError(f"start state has det F = {ev.min_j:.3g} <= 0", stats)
    for it in range(cfg.max_iterations + 1):
        du_d = g - u
        du_d[free] = 0.0
        res = _relative_residual(p, ev.r)
        stats = replace(stats, residual=res, min_det_f=ev.min_j)
        prescribed_done = not np.any(du_d)
        if prescribed_done and (res <= cfg.rtol or np.linalg.norm(ev.r[free]) < 1e-13):
            return u, replace(stats, iterations=stats.iterations + it)
        if it == cfg.max_iterations:
            break
        Ke = _tangent(p, ev, exact_contact=res < EXACT_CONTACT_BELOW)
        coupled = apply_matrix(p.pattern, Ke, du_d)
        K = assemble_matrix(p.pattern, Ke)
        if p.taylor_hood:  # the reduced Hessian K + G^T M^-1 G, never formed (mixed.py)
            G = _coupling(p, ev)
            coupled += mixed.reduced_product(p.pressure, G, du_d)
            K = mixed.Tangent(K, G[:, free].tocsr(), p.pressure)
        rhs = -(ev.r + coupled)[free]
        step = du_d.copy()
        step[free], stats = _solve_linearised(p, cache, K, rhs, stats)
        try:
            u, ev = _line_search(p, u, step, ev, prescribed_done, stats)
        except ConvergenceError:
            if not cache.factor.float32:
                raise
            # The correction came through float32 factors (CG to CG_RTOL, or their own solve). On an
            # ill-conditioned tangent (a stiffness contrast of 1e4) it can fail to lower the energy
            # where the exact Newton step does: solve exactly with float64 factors, kept from here on.
            cache.factor = K.factorise(float32=False) if isinstance(K, mixed.Tangent) else Factor(K)
            stats = replace(stats, factorizations=stats.factorizations + 1)
            step = du_d.copy()
            step[free] = cache.factor.solve(rhs)
            u, ev = _line_search(p, u, step, ev, prescribed_done, stats)
    raise ConvergenceError(
        f"Newton did not converge in {cfg.max_iterations} iterations (relative residual {stats.residual:.2e})", stats
    )


def _line_search(p: Problem, u, step, ev: Eval, prescribed_done: bool, stats: Stats):
    """Backtrack alpha = 1, 1/2, ... until det F > 0 everywhere and, once u_D = g, Armijo holds.

    Equilibrium minimises the potential Pi, so with the constraints met the Newton direction must
    lower Pi (Armijo, slope r . du); this guards against steps past a limit point, where the
    residual norm alone can mislead. While a guide increment is still being applied, any admissible
    (det F > 0) step is taken.
    """
    alpha, slope = 1.0, float(ev.r[p.free] @ step[p.free])
    for _ in range(10):
        trial = u + alpha * step
        new = residual(p, trial)
        armijo = new.pi <= ev.pi + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * abs(ev.pi)
        if new.r is not None and (not prescribed_done or armijo):
            return trial, new
        alpha *= 0.5
    raise ConvergenceError("line search found no step with det F > 0 that lowers the potential energy", stats)
