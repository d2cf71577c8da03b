"""Path continuation in the guide displacement: load steps, the path predictor and step halving.

A path at one angle beta visits d_1 < d_2 < ... . Between converged states it moves in load steps
of at most solver.max_step_mm; each step starts Newton (newton.py) from a Lagrange extrapolation
through up to three converged states, and a step that fails is halved, up to solver.max_halvings
times. With gravity on, the path starts from the gravity-loaded state (loaded in 4 steps).
With the guide in contact (contact.py), each step ends with augmented-Lagrangian updates of the
contact multipliers, a Newton solve after each, until the wall's deepest penetration into the tip
is below guide.contact_tol_mm; the next step starts from that equilibrium's pressures.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from fem_offline.fe import contact as ct
from fem_offline.fe.newton import ConvergenceError, FactorCache, Stats, newton
from fem_offline.fe.problem import Problem

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PathState:
    """What a displacement path carries from one converged step to the next."""

    u: np.ndarray  # (n_dofs,)
    d_mm: float = 0.0
    history: tuple[tuple[float, np.ndarray], ...] = ()  # up to two earlier (d, u) for the predictor
    cache: FactorCache = field(default_factory=FactorCache)  # shared along the path (newton.py)
    multipliers: np.ndarray | None = None  # (f, q) the contact multipliers u is in equilibrium with (contact.py)


def predict(state: PathState, d_mm: float) -> np.ndarray:
    """Extrapolate along the path (Lagrange, through up to three converged states)."""
    ds = [d for d, _ in state.history] + [state.d_mm]
    us = [u for _, u in state.history] + [state.u]
    guess = np.zeros_like(state.u)
    for i, (di, ui) in enumerate(zip(ds, us)):
        weight = np.prod([(d_mm - dj) / (di - dj) for j, dj in enumerate(ds) if j != i])
        guess += weight * ui
    return guess


MAX_CONTACT_UPDATES = 30


def settle_contact(problem: Problem, u: np.ndarray, g: np.ndarray, cache: FactorCache,
                   stats: Stats) -> tuple[np.ndarray, np.ndarray, Stats]:
    """Uzawa: lam <- t and re-solve until the deepest penetration is <= contact_tol_mm.

    `problem` is at the guide position with the multipliers to start from (Problem.at_guide).
    Returns (u, the multipliers u is in equilibrium with, stats): evaluated with them, contact.evaluate
    gives the pressures of that equilibrium. Raises ConvergenceError when the updates do not settle.
    """
    surface, load = problem.contact, problem.contact_load
    for update in range(MAX_CONTACT_UPDATES + 1):
        touch = ct.evaluate(surface, u, load)
        depth = float(max(touch.penetration.max(), 0.0))
        if depth <= surface.tol_mm:
            return u, load.multipliers, replace(stats, contact_updates=stats.contact_updates + update,
                                                penetration_mm=depth)
        if update == MAX_CONTACT_UPDATES:
            break
        load = ct.Load(load.centre, touch.pressure)
        u, stats = newton(replace(problem, contact_load=load), u, g, cache, stats)
    raise ConvergenceError(f"contact: penetration {depth:.3g} mm after {MAX_CONTACT_UPDATES} multiplier updates "
                           f"(guide.contact_tol_mm = {surface.tol_mm:g})", stats)


def _next_multipliers(problem: Problem, state: PathState, angle_deg: float) -> np.ndarray | None:
    """Where the next step's multipliers start: the pressures of the last equilibrium, an Uzawa update
    merged into the step (the penetration left is then the pressure's growth over one step / k, so a
    step seldom needs an update of its own)."""
    if problem.contact is None or state.multipliers is None:
        return state.multipliers
    last = problem.at_guide(state.d_mm, angle_deg, state.multipliers).contact_load
    return ct.evaluate(problem.contact, state.u, last).pressure


def advance(problem: Problem, state: PathState, d_mm: float, angle_deg: float, stats: Stats,
            depth: int = 0) -> tuple[PathState, Stats]:
    """The path state at guide displacement d_mm, halving the load step on failure; and stats + the work."""
    g = problem.dirichlet(d_mm, angle_deg)
    loaded = problem.at_guide(d_mm, angle_deg, _next_multipliers(problem, state, angle_deg))
    guess = predict(state, d_mm)
    if problem.nonlinear and problem.min_jacobian(guess) <= 0:
        guess = state.u
    multipliers = None
    try:
        u, stats = newton(loaded, guess, g, state.cache, stats)
        if problem.contact is not None:
            u, multipliers, stats = settle_contact(loaded, u, g, state.cache, stats)
    except ConvergenceError as exc:
        if depth >= problem.scene.solver.max_halvings:
            raise
        stats = replace(exc.stats, halvings=exc.stats.halvings + 1)
        log.info("halving load step %.4g -> %.4g mm", state.d_mm, d_mm)
        state, stats = advance(problem, state, 0.5 * (state.d_mm + d_mm), angle_deg, stats, depth + 1)
        return advance(problem, state, d_mm, angle_deg, stats, depth + 1)
    history = (*state.history[-1:], (state.d_mm, state.u))
    return replace(state, u=u, d_mm=d_mm, history=history, multipliers=multipliers), stats


def initial_state(problem: Problem) -> PathState:
    """Reference state, or the gravity-loaded state when gravity is on (loaded in 4 steps)."""
    state = PathState(np.zeros(problem.n_dofs))
    if problem.body_force is None:
        return state
    full = problem.body_force
    for s in (0.25, 0.5, 0.75, 1.0):
        scaled = replace(problem, body_force=s * full)
        u, _ = newton(scaled, state.u, np.zeros(problem.n_dofs), state.cache)
        state = replace(state, u=u)
    return state


def solve_path(problem: Problem, displacements_mm, angle_deg: float, state: PathState | None = None,
               with_state: bool = False):
    """Yield (d_mm, u (n_nodes, 3), Stats) for increasing guide displacements at one angle, and the
    PathState after each when `with_state` (to checkpoint a path, convergence.solve_resumable)."""
    if state is None:
        state = initial_state(problem)
    max_step = problem.scene.solver.max_step_mm
    for d in displacements_mm:
        stats, t0 = Stats(), time.perf_counter()
        n_sub = max(1, int(np.ceil(abs(d - state.d_mm) / max_step - 1e-9)))
        for target in np.linspace(state.d_mm, d, n_sub + 1)[1:]:
            last = state.d_mm
            try:
                state, stats = advance(problem, state, float(target), angle_deg, stats)
            except ConvergenceError as exc:
                raise ConvergenceError(
                    f"no equilibrium found for guide displacement {target:.4g} mm at beta {angle_deg:g} deg "
                    f"(last converged: {last:.4g} mm; load step halved {problem.scene.solver.max_halvings} times): "
                    f"{exc}", exc.stats,
                ) from None
            log.info("%.4g mm at beta %g deg: %d Newton iterations, %d CG, %d factorisations, %.1f s so far",
                     target, angle_deg, stats.iterations, stats.cg_iterations, stats.factorizations,
                     time.perf_counter() - t0)
        out = (float(d), state.u.reshape(-1, 3).copy(), replace(stats, seconds=time.perf_counter() - t0))
        yield (*out, state) if with_state else out
