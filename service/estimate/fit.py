"""The state from tracked points: Levenberg-Marquardt on the surrogate, with a Laplace covariance.

The state x = (d mm, beta deg) and, for a material model, theta_i = ln(E_i / E_i,nominal) per tissue. Tracked
point j (reference position X_j, observed deformed position y_j, noise std s_j per coordinate) and the priors give

    r(x) = [ (X_j + u_j(x) - y_j) / s_j  for every j ;  (x_i - mu_i) / tau_i  for every prior ]
    x^ = argmin |r(x)|^2  inside the envelope (and the stiffness ranges)       (Levenberg-Marquardt, projected)
    Sigma = (J^T J + P_env)^-1                                                 (Laplace, J = dr/dx at x^)

u(x) comes from the graph; J by central differences, all of one iteration's states decoded in one onnxruntime call
(the graph is linear in theta, so those columns are exact). P_env = diag(12 / width^2), the precision of the
envelope taken as a uniform prior: it keeps Sigma finite where the points say nothing (at d = 0, beta moves
nothing) and counts for little elsewhere. A target (a lesion, in reference coordinates) is then at X_t + u_t(x^)
with covariance J_t Sigma J_t^T.

The fit is flagged as contradicting the model when |r|^2 is beyond the chi-square's 1 - ALPHA quantile for its
degrees of freedom, or when a point's own normalised residual |r_j|^2 is beyond the chi-square(3) quantile at
ALPHA / (number of points) (Bonferroni): an outlier.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from contracts.tet10 import p2_weights

from ..model import Predictor

ALPHA = 1e-3  # the false-alarm rate of the contradiction flag, per fit
DIFF_STEP = (0.01, 0.01, 0.1)  # central-difference steps: mm, deg, ln E (exact for theta: the graph is linear in it)
GRID = (9, 9)  # the (d, beta) grid the fit starts from when there is no previous state
MAX_ITERATIONS = 40
RCOND = 1e-5  # singular values of the scaled Jacobian below this fraction of the largest: directions not moved along
STEP_TOL = 1e-6  # relative step (mm, deg, ln E) at which the fit has converged, whatever the std
STEP_SIGMA = 1e-4  # a step under this fraction of each parameter's std: converged
REJECTED_SIGMA = 1e-2  # a step this small that does not lower the cost: converged (float32 noise decides there)


@dataclass(frozen=True)
class StateSpace:
    """The parameters of a model's state, their bounds and difference steps."""

    names: tuple[str, ...]  # displacement_mm, angle_deg, then ln_E_<tissue> per material input
    lower: np.ndarray  # (n,)
    upper: np.ndarray  # (n,)
    steps: np.ndarray  # (n,) central-difference steps

    @classmethod
    def of(cls, predictor: Predictor) -> StateSpace:
        m = predictor.manifest
        lo = [m.envelope.displacement_mm[0], m.envelope.angle_deg[0]]
        hi = [m.envelope.displacement_mm[1], m.envelope.angle_deg[1]]
        names, steps = ["displacement_mm", "angle_deg"], [DIFF_STEP[0], DIFF_STEP[1]]
        for inp in m.materials.inputs if m.materials is not None else []:
            names.append(f"ln_E_{inp.tissue}")
            lo.append(math.log(inp.youngs_kpa_range[0] / inp.nominal_youngs_kpa))
            hi.append(math.log(inp.youngs_kpa_range[1] / inp.nominal_youngs_kpa))
            steps.append(DIFF_STEP[2])
        return cls(tuple(names), np.array(lo), np.array(hi), np.array(steps))

    @property
    def n_materials(self) -> int:
        return len(self.names) - 2

    def envelope_precision(self) -> np.ndarray:
        """(n,) 12 / width^2: each bound pair as a uniform prior's precision."""
        return 12.0 / np.maximum(self.upper - self.lower, 1e-9) ** 2


def model_sigma_mm(predictor: Predictor, points: np.ndarray) -> np.ndarray:
    """(k,) the model's own error at reference points, 1 sigma: half the manifest's bound (as the error budget
    counts 2 sigma) of the model against its own FE, over the stiffness ranges for a material model (materials
    accuracy: model_mm), else the surrogate's; the markers' bound for a point in the prostate (the markers are
    prostate nodes), every node's elsewhere. The FE's discretisation error is not in it: it is the same bias at
    every state (the reply's error budget states it)."""
    m = predictor.manifest
    mat = m.materials.accuracy if m.materials is not None else None

    def bound(region: str) -> float:
        if mat is not None and region in mat.regions:
            return mat.regions[region].model_mm
        acc = m.accuracy.regions.get(region) or m.accuracy.regions.get("all_nodes")
        return acc.surrogate_mm if acc is not None else 0.0

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(points):
        return np.zeros(0)
    tet, _ = predictor.locator.locate(points)
    tissues = m.mesh.tissues
    inside = (tet >= 0) & ("prostate" in tissues) & (predictor.folder.mesh.tissue[np.maximum(tet, 0)]
                                                     == (tissues.index("prostate") if "prostate" in tissues else -1))
    return np.where(inside, bound("markers"), bound("all_nodes")) / 2.0


@dataclass(frozen=True)
class PointSet:
    """Reference points read from decoded nodes: position_k = reference_k + weights[k] @ u(nodes)."""

    nodes: np.ndarray  # (n,) mesh node ids to decode
    weights: np.ndarray  # (k, n) float64: 1 at a marker's node, P2 shape functions at a point in its tet
    reference: np.ndarray  # (k, 3) float64 reference positions, mm


def point_set(predictor: Predictor, *, node_ids: np.ndarray, points: np.ndarray) -> PointSet:
    """Mesh nodes (markers) followed by reference points; OutsideMesh names the first point in no tet."""
    node_ids, points = np.asarray(node_ids, dtype=np.int64), np.asarray(points, dtype=np.float64).reshape(-1, 3)
    parts = [node_ids]
    if len(points):
        unique, inverse, bary = predictor.locate(points)
        parts.append(unique)
    nodes = np.unique(np.concatenate(parts))
    weights = np.zeros((len(node_ids) + len(points), len(nodes)))
    weights[np.arange(len(node_ids)), np.searchsorted(nodes, node_ids)] = 1.0
    if len(points):
        rows = len(node_ids) + np.arange(len(points))
        np.add.at(weights, (rows[:, None], np.searchsorted(nodes, unique[inverse])), p2_weights(bary))
    reference = np.concatenate([predictor.folder.nodes[node_ids], points])
    return PointSet(nodes, weights, reference)


def positions(predictor: Predictor, space: StateSpace, points: PointSet, states: np.ndarray) -> np.ndarray:
    """(b, k, 3) float64 deformed positions of `points` at each state (b, n): one onnxruntime call."""
    states = np.atleast_2d(states)
    if space.n_materials:
        materials = np.zeros((len(states), 2, space.n_materials), dtype=np.float32)
        materials[:, 0] = states[:, 2:]
        u, _ = predictor.decode_std(states[:, :2], points.nodes, materials)
    else:
        u = predictor.decode(states[:, :2], points.nodes)
    return points.reference + np.einsum("kn,bnc->bkc", points.weights, u.astype(np.float64))


def with_jacobian(predictor: Predictor, space: StateSpace, points: PointSet,
                  x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (k, 3) at x and their Jacobian (k, 3, n) by central differences, in one decode."""
    n = len(x)
    shifts = np.diag(space.steps)
    out = positions(predictor, space, points, np.concatenate([x[None], x + shifts, x - shifts]))
    jac = (out[1:n + 1] - out[n + 1:]) / (2 * space.steps[:, None, None])  # (n, k, 3)
    return out[0], np.moveaxis(jac, 0, -1)


@dataclass(frozen=True)
class Problem:
    """What the fit knows: tracked points (the first `n_obs` of `points`) and priors on the state."""

    points: PointSet  # observed points first, then the targets
    n_obs: int
    observed: np.ndarray  # (n_obs, 3) observed deformed positions, mm
    noise_mm: np.ndarray  # (n_obs,) 1-sigma per coordinate
    prior_mean: np.ndarray  # (n,) ; used where prior_std is finite
    prior_std: np.ndarray  # (n,) ; inf: no prior on that parameter
    target_sigma_mm: np.ndarray | None = None  # (t,) the model's own error at each target, 1 sigma (model_sigma_mm)


@dataclass(frozen=True)
class Estimate:
    x: np.ndarray  # (n,) the state
    covariance: np.ndarray  # (n, n)
    targets: np.ndarray  # (t, 3) displaced target positions, mm
    target_covariance: np.ndarray  # (t, 3, 3)
    predicted: np.ndarray  # (n_obs, 3) the model's positions of the observed points at x
    normalised: np.ndarray  # (n_obs,) |residual_j / s_j|^2 per observed point
    chi2: float  # |r|^2, points and priors
    dof: int  # residual terms minus parameters
    p_value: float | None  # None when dof <= 0
    outliers: tuple[int, ...]  # observed points beyond the Bonferroni quantile
    iterations: int
    converged: bool
    at_bound: tuple[int, ...]  # parameters the fit ended on a bound of

    @property
    def contradiction(self) -> bool:
        return bool(self.outliers) or (self.p_value is not None and self.p_value < ALPHA)


def _residual(problem: Problem, x: np.ndarray, pos: np.ndarray, jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The residual vector and its Jacobian from the positions and Jacobian of all points."""
    k, s = problem.n_obs, problem.noise_mm[:, None]
    r_obs = ((pos[:k] - problem.observed) / s).ravel()
    j_obs = (jac[:k] / s[..., None]).reshape(3 * k, -1)
    has = np.isfinite(problem.prior_std)
    r_prior = (x[has] - problem.prior_mean[has]) / problem.prior_std[has]
    j_prior = np.eye(len(x))[has] / problem.prior_std[has, None]
    return np.concatenate([r_obs, r_prior]), np.vstack([j_obs, j_prior])


def start(predictor: Predictor, space: StateSpace, problem: Problem) -> np.ndarray:
    """The best state of a (d, beta) grid over the envelope, stiffnesses at their prior mean (or nominal)."""
    theta = np.where(np.isfinite(problem.prior_std[2:]), problem.prior_mean[2:], 0.0)
    d, b = np.meshgrid(np.linspace(space.lower[0], space.upper[0], GRID[0]),
                       np.linspace(space.lower[1], space.upper[1], GRID[1]), indexing="ij")
    states = np.column_stack([d.ravel(), b.ravel(), np.tile(theta, (d.size, 1))])
    k = problem.n_obs
    obs = PointSet(problem.points.nodes, problem.points.weights[:k], problem.points.reference[:k])
    pos = positions(predictor, space, obs, states)  # (grid, k, 3)
    costs = ((((pos - problem.observed) / problem.noise_mm[:, None]) ** 2).sum(axis=(1, 2))
             + (((states - problem.prior_mean) / problem.prior_std) ** 2).sum(axis=1))  # inf std: 0
    return states[int(np.argmin(costs))]


def estimate(predictor: Predictor, space: StateSpace, problem: Problem, x0: np.ndarray | None = None) -> Estimate:
    """Fit the state to the observed points and priors from `x0` (default: the best of a grid); see the module doc."""
    x = np.clip(start(predictor, space, problem) if x0 is None else np.asarray(x0, dtype=np.float64),
                space.lower, space.upper)
    pos, jac = with_jacobian(predictor, space, problem.points, x)
    r, j = _residual(problem, x, pos, jac)
    cost, lam, converged, it = float(r @ r), 1e-3, False, 0
    for it in range(1, MAX_ITERATIONS + 1):  # noqa: B007 -- its last value is the iteration count
        step = _bounded_step(space, x, j, r, lam)
        if _negligible(space, step, x, j):
            converged = True
            break
        x_new = np.clip(x + step, space.lower, space.upper)  # clip: rounding only, the step stays inside
        pos_new, jac_new = with_jacobian(predictor, space, problem.points, x_new)
        r_new, j_new = _residual(problem, x_new, pos_new, jac_new)
        cost_new = float(r_new @ r_new)
        if cost_new <= cost:
            small = _negligible(space, x_new - x, x, j) or cost - cost_new <= 1e-10 * (1 + cost)
            x, pos, jac, r, j, cost, lam = x_new, pos_new, jac_new, r_new, j_new, cost_new, max(lam / 10, 1e-9)
            if small:
                converged = True
                break
        else:
            lam *= 10
            # no step lowers the cost: a (bounded) minimum, or steps so small the float32 decode's noise decides
            if lam > 1e8 or _negligible(space, step, x, j, sigmas=REJECTED_SIGMA):
                converged = True
                break
    return _laplace(space, problem, x, pos, jac, r, j, it, converged)


def _negligible(space: StateSpace, step: np.ndarray, x: np.ndarray, j: np.ndarray, *, sigmas: float = 0.0) -> bool:
    """Whether a step is nothing: under STEP_SIGMA (or `sigmas`) of each parameter's std (the Laplace
    covariance's), or at the decode's float32 resolution."""
    std = np.sqrt(np.diag(np.linalg.inv(j.T @ j + np.diag(space.envelope_precision()))))
    return bool(np.all(np.abs(step) <= np.maximum(max(STEP_SIGMA, sigmas) * std, STEP_TOL * (1 + np.abs(x)))))


def _bounded_step(space: StateSpace, x: np.ndarray, j: np.ndarray, r: np.ndarray, lam: float) -> np.ndarray:
    """The step with the parameters on a bound that it would push out held there (active set), shortened to stay
    inside the bounds. Clipping each parameter instead would move the fit along directions the points do not see."""
    free = np.ones(len(x), dtype=bool)
    while True:
        step = np.zeros(len(x))
        if free.any():
            step[free] = _step(j[:, free], r, lam)
        out = free & (((x <= space.lower) & (step < 0)) | ((x >= space.upper) & (step > 0)))
        if not out.any():
            break
        free &= ~out
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(step > 0, (space.upper - x) / step, np.where(step < 0, (space.lower - x) / step, np.inf))
    return step * min(1.0, float(room.min()))


def _step(j: np.ndarray, r: np.ndarray, lam: float) -> np.ndarray:
    """The damped Gauss-Newton step in columns scaled to unit norm, by SVD: directions the residual does not see
    (singular value under RCOND of the largest; e.g. every stiffness scaled together under a prescribed push, when
    every load-bearing tissue is an input) are not moved along, so the fit stays where it started in them."""
    norms = np.linalg.norm(j, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    u, sv, vt = np.linalg.svd(j / norms, full_matrices=False)
    if sv.max() <= 0:
        return np.zeros(j.shape[1])
    keep = sv > RCOND * sv.max()
    gain = np.where(keep, sv / (sv**2 + lam * sv.max() ** 2 + (~keep)), 0.0)
    return -(vt.T @ (gain * (u.T @ r))) / norms


def _laplace(space, problem, x, pos, jac, r, j, iterations, converged) -> Estimate:
    """The Laplace covariance at the fit, the targets' covariance and the fit's tests."""
    cov = np.linalg.inv(j.T @ j + np.diag(space.envelope_precision()))
    cov = (cov + cov.T) / 2
    k = problem.n_obs
    jt = jac[k:]  # (t, 3, n)
    target_cov = np.einsum("tan,nm,tbm->tab", jt, cov, jt)
    if problem.target_sigma_mm is not None:
        target_cov = target_cov + problem.target_sigma_mm[:, None, None] ** 2 * np.eye(3)
    normalised = (((pos[:k] - problem.observed) / problem.noise_mm[:, None]) ** 2).sum(axis=1)
    chi2, dof = float(r @ r), len(r) - len(x)
    p_value = float(stats.chi2.sf(chi2, dof)) if dof > 0 else None
    limit = stats.chi2.isf(ALPHA / max(k, 1), 3)
    outliers = tuple(int(i) for i in np.flatnonzero(normalised > limit)) if dof > 0 else ()
    span = space.upper - space.lower
    at_bound = tuple(int(i) for i in np.flatnonzero((x - space.lower <= 1e-6 * span)
                                                    | (space.upper - x <= 1e-6 * span)))
    return Estimate(x, cov, pos[k:], target_cov, pos[:k], normalised, chi2, dof, p_value, outliers, iterations,
                    converged, at_bound)

