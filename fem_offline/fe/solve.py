"""One case, (guide displacement, angle) -> displacement field: the entry point over both models.

Linear model with a glued guide: superposition of unit fields (linear.py). Nonlinear, or with the
guide in contact (contact.py): load-stepped from rest by path continuation (continuation.py), with
Newton and a line search at each step (newton.py).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from fem_offline.fe.continuation import solve_path
from fem_offline.fe.linear import linear_modes, superpose
from fem_offline.fe.newton import Stats
from fem_offline.fe.problem import Problem


def solve_case(problem: Problem, displacement_mm: float, angle_deg: float,
               step_mm: float | None = None) -> tuple[np.ndarray, Stats]:
    """One case: (u (n_nodes, 3), Stats). Path-solved cases are load-stepped from zero in steps <= step_mm."""
    t0 = time.perf_counter()
    if problem.superposable:
        u = superpose(linear_modes(problem), displacement_mm, angle_deg)
        return u, Stats(factorizations=1, seconds=time.perf_counter() - t0)
    if step_mm is not None:
        problem = problem.with_solver(max_step_mm=step_mm)
    (_, u, stats), = solve_path(problem, [displacement_mm], angle_deg)
    return u, replace(stats, seconds=time.perf_counter() - t0)
