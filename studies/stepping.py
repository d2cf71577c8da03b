"""One displacement path from rest, step by step, with the solver's work summed over its steps."""

from __future__ import annotations

import time

import numpy as np

from fem_offline.fe.continuation import solve_path

WORK = ("newton", "cg", "factorisations", "contact_updates", "halvings")


def stepped_path(problem, angle_deg: float, to_mm: float, *, verbose: bool = True) -> tuple[np.ndarray, dict]:
    """Solve the path in the scene's sweep steps to `to_mm`: (u (n_steps, n_nodes, 3), totals of WORK, seconds, steps).

    With `verbose`, one line a step: Newton and CG iterations, factorisations, multiplier updates, time, min det F.
    """
    step = problem.scene.sweep.displacement_step_mm
    ds = np.arange(step, to_mm + 1e-9, step)
    fields, total = [], dict.fromkeys(WORK, 0)
    t0 = time.perf_counter()
    for d, u, st in solve_path(problem, ds, angle_deg):
        fields.append(u)
        for key, value in zip(WORK, (st.iterations, st.cg_iterations, st.factorizations, st.contact_updates,
                                     st.halvings)):
            total[key] += value
        if verbose:
            print(f"  {d:6.2f} mm: Newton {st.iterations:3d}, CG {st.cg_iterations:4d}, factorisations "
                  f"{st.factorizations:2d}, updates {st.contact_updates:2d}, {st.seconds:6.2f} s, min det F "
                  f"{st.min_det_f:.3f}", flush=True)
    return np.stack(fields), {**total, "seconds": time.perf_counter() - t0, "steps": len(ds)}
