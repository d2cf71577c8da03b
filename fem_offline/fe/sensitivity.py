"""How an equilibrium moves with each tissue's stiffness: du/d ln E_i, one tangent solve per tissue.

At equilibrium r(u; E) = 0 on the free DOFs, with u = g on the prescribed ones. At fixed nu, mu and lambda
are proportional to E, and the neo-Hookean energy (with the Taylor-Hood pressure term, a P1 pressure per
tissue) is linear in (mu, lambda), so

    d r / d ln E_i = f_i(u),      the internal force of tissue i's elements alone,
    K_T  S_i = -f_i(u)            on the free DOFs,  S_i = du/d ln E_i,  S_i = 0 where u is prescribed,

K_T the exact tangent at u (contact curvature included). f_i is taken as r(u; E_i x 2) - r(u; E), exact by
that linearity, so every element variant is covered by the residual that the solver itself uses.

With the guide prescribing displacements and gravity off, scaling every E by one factor leaves u unchanged:
only stiffness ratios matter, and sum_i S_i = 0 over the assembled tissues. With the tip in contact, the points that
press on it are held there to first order (B S = 0, _constrained): the contact pressure is a reaction, so its change
comes from the constraint, not from the penalty's compliance, and the sum is zero with the tip in contact too.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse.linalg import LinearOperator, cg

from fem_offline.fe import contact as ct
from fem_offline.fe import mixed
from fem_offline.fe.linsolve import Factor
from fem_offline.fe.newton import residual, tangent_operator
from fem_offline.fe.problem import Problem, build_problem


@dataclass(frozen=True)
class Stiffened:
    """The problem, and per soft tissue the same problem with that tissue's E doubled (built once per mesh)."""

    problem: Problem
    doubled: dict[str, Problem]

    @property
    def tissues(self) -> tuple[str, ...]:
        return tuple(self.doubled)


def soft_tissues(problem: Problem) -> tuple[str, ...]:
    """The tissues whose stiffness can move u: those with assembled (not fully constrained) tets."""
    mesh = problem.mesh
    present = np.unique(mesh.tissue[problem.active]) if problem.active is not None else np.unique(mesh.tissue)
    return tuple(mesh.tissue_names[i] for i in present)


def stiffened(problem: Problem, tissues: tuple[str, ...] | None = None) -> Stiffened:
    """Build the doubled-E problems for `tissues` (default: every soft tissue)."""
    names = soft_tissues(problem) if tissues is None else tissues
    doubled = {}
    for name in names:
        tissue = problem.scene.tissues[name]
        twice = tissue.model_copy(update={"youngs_kpa": 2.0 * tissue.youngs, "shear_wave_speed_m_s": None})
        scene = problem.scene.model_copy(update={"tissues": {**problem.scene.tissues, name: twice}})
        doubled[name] = build_problem(scene, problem.mesh)
    return Stiffened(problem, doubled)


def tissue_force(models: Stiffened, loaded: Problem, u: np.ndarray, name: str) -> np.ndarray:
    """f_i(u) (n_dofs,): d r / d ln E_i at u, with the guide and contact load of `loaded`."""
    twice = replace(models.doubled[name], contact_load=loaded.contact_load)
    if twice.contact is not None:  # the contact pressure is a reaction, not a tissue's force: the same penalty
        twice = replace(twice, contact=loaded.contact)
    return residual(twice, u).r - residual(loaded, u).r


# CG on the contact points' Schur complement stops at this relative residual (_constrained)
CONSTRAINT_RTOL = 1e-6


def _constrained(factor, loaded: Problem, u: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """S (n_dofs,) of K S = rhs + B^T mu with the contact points that press (t > 0) held on the tip to first order,
    B S = 0, (B S)_q = n_q . dx_q: mu from (B K^-1 B^T) mu = -B K^-1 rhs by CG, one back-substitution a step.

    With the penalty alone, K S = rhs, S carries the penalty's compliance and sum_i S_i is not zero. Held exactly, the
    tissues' forces that balance the tip (sum_i f_i = -r_contact, along the pressed normals) are taken by mu, and
    sum_i S_i = 0. On the constrained directions the penalty's k B^T B vanishes, so K stands for the elastic tangent.
    """
    free = loaded.free

    def solve(b):
        s = np.zeros(loaded.n_dofs)
        s[free] = factor.solve(b[free])
        return s

    s0 = solve(rhs)
    surface = loaded.contact
    if surface is None:
        return s0
    on = ct.evaluate(surface, u, loaded.contact_load).pressure > 0
    if not on.any():
        return s0
    normal = ct.evaluate(surface, u, loaded.contact_load).normal[on]  # (m, 3)
    N, edofs = surface.N[on], np.repeat(surface.edofs[:, None, :], surface.shape[1], axis=1)[on]  # (m, 10), (m, 30)

    def B(s):  # (m,) normal motion of each pressed point
        return np.einsum("qi,qa,qai->q", normal, N, s[edofs].reshape(-1, 10, 3))

    def Bt(mu):  # (n_dofs,) the forces mu along the normals
        return np.bincount(edofs.ravel(), weights=np.einsum("q,qa,qi->qai", mu, N, normal).ravel(),
                           minlength=loaded.n_dofs)

    schur = LinearOperator((len(N), len(N)), matvec=lambda mu: B(solve(Bt(np.ravel(mu)))), dtype=np.float64)
    target = -B(s0)
    if not np.abs(target).max() > 0:
        return s0
    # K holds the penalty k B^T diag(w) B, so B K^-1 B^T is near (k w)^-1 on what presses: k w preconditions it
    kw = surface.stiffness * surface.w[on]
    precondition = LinearOperator(schur.shape, matvec=lambda r: kw * np.ravel(r), dtype=np.float64)
    mu, _ = cg(schur, target, rtol=CONSTRAINT_RTOL, maxiter=500, M=precondition)
    return s0 + solve(Bt(mu))


def sensitivities(models: Stiffened, loaded: Problem, u: np.ndarray) -> dict[str, np.ndarray]:
    """S_i = du/d ln E_i (n_nodes, 3) in mm per unit ln E, at the equilibrium u (n_dofs,) of `loaded`.

    `loaded` is models.problem at the state's guide position and contact multipliers (Problem.at_guide).
    """
    K, _ = tangent_operator(loaded, u)
    factor = K.factorise(float32=False) if isinstance(K, mixed.Tangent) else Factor(K)
    return {name: _constrained(factor, loaded, u, -tissue_force(models, loaded, u, name)).reshape(-1, 3)
            for name in models.tissues}


def first_order(u: np.ndarray, sens: dict[str, np.ndarray], log_ratio: dict[str, float]) -> np.ndarray:
    """u + sum_i S_i ln(E_i / E_i0): the answer at other stiffnesses, to first order in ln E."""
    return u + sum(sens[name] * log_ratio.get(name, 0.0) for name in sens)


def propagated_std(sens: dict[str, np.ndarray], log_std: dict[str, float]) -> np.ndarray:
    """Per node and component (n_nodes, 3): sqrt(sum_i (S_i sigma_i)^2), independent ln E_i with std sigma_i."""
    return np.sqrt(sum((sens[name] * log_std.get(name, 0.0)) ** 2 for name in sens))
