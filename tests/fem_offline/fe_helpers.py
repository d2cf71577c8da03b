"""Small drivers over the product's kernels for verification problems on plain skfem meshes."""

import numpy as np
from skfem import Basis, ElementTetP2

from fem_offline.fe import elasticity as el
from fem_offline.fe import mixed
from fem_offline.fe.assembly import apply_matrix, assemble_matrix, assemble_vector, build_pattern
from fem_offline.fe.linsolve import Factor
from fem_offline.fe.materials import lame_kpa


def p2_data(mesh, intorder=2):
    """P2 nodes (n, 3), element nodes (m, 10), gradients G (m, q, 10, 3), weights W (m, q), basis."""
    basis = Basis(mesh, ElementTetP2(), intorder=intorder)
    G = np.stack([basis.basis[a][0].grad for a in range(10)]).transpose(2, 3, 0, 1)
    return basis.doflocs.T, basis.element_dofs.T, np.ascontiguousarray(G), basis.dx, basis


def lame_params(youngs, poisson, n):
    mu, lam = lame_kpa(youngs, poisson)
    return np.full(n, mu), np.full(n, lam)


def taylor_hood_space(basis, tets, W, lam, pattern, tissue=None):
    """The P1 pressure space (fem_offline/fe/mixed.py) of a plain skfem P2 basis' mesh."""
    from skfem import ElementTetP1

    p1 = Basis(basis.mesh, ElementTetP1(), quadrature=basis.quadrature)
    N = np.stack([np.asarray(p1.basis[a][0]) for a in range(4)], axis=-1)
    tissue = np.zeros(len(tets), int) if tissue is None else tissue
    return mixed.pressure_space(p1.element_dofs.T, N, W, tissue, lam, pattern.edofs)


def solve_linear(tets, n_nodes, G, W, mu, lam, fixed_dofs, g, f_ext, md=False, basis=None, tissue=None):
    """u with u[fixed] = g[fixed] and K u = f_ext on the free DOFs (md: mean dilatation; with the
    P2 `basis` given, Taylor-Hood P2/P1 with a pressure per `tissue`, solved through its saddle point)."""
    free = np.setdiff1d(np.arange(3 * n_nodes), fixed_dofs)
    pattern = build_pattern(tets, n_nodes, free)
    u = np.where(np.isin(np.arange(3 * n_nodes), fixed_dofs), g, 0.0)
    if basis is not None:
        Ke = el.linear_stiffness(G, W, mu, np.zeros_like(lam))
        pressure = taylor_hood_space(basis, tets, W, lam, pattern, tissue)
        C = pressure.coupling(W, G, 3 * n_nodes)
        rhs = f_ext - apply_matrix(pattern, Ke, u) - mixed.reduced_product(pressure, C, u)
        u[free] = mixed.Tangent(assemble_matrix(pattern, Ke), C[:, free].tocsr(), pressure).factorise().solve(rhs[free])
        return u, pattern
    Ke = el.linear_stiffness(G, W, mu, lam, md)
    rhs = f_ext - apply_matrix(pattern, Ke, u)
    u[free] = Factor(assemble_matrix(pattern, Ke)).solve(rhs[free])
    return u, pattern


def internal_force_nh(pattern, G, W, mu, lam, u, md=False):
    H = el.displacement_gradient(G, u[pattern.edofs].reshape(-1, 10, 3))
    P, _, _ = el.neo_hookean_stress(H, mu, lam, W if md else None)
    return assemble_vector(pattern, el.internal_force(G, W, P))


def _octant_shell(a, b, size):
    """One octant of the thick sphere a < r < b, graded: the faceted inner sphere is the dominant error."""
    import gmsh
    from skfem import MeshTet

    gmsh.initialize(interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        occ = gmsh.model.occ
        shell, _ = occ.cut([(3, occ.addSphere(0, 0, 0, b))], [(3, occ.addSphere(0, 0, 0, a))])
        occ.intersect(shell, [(3, occ.addBox(0, 0, 0, 2 * b, 2 * b, 2 * b))])
        occ.synchronize()
        gmsh.model.mesh.setSizeCallback(
            lambda dim, tag, x, y, z, lc: size * (0.25 + 0.75 * (np.sqrt(x * x + y * y + z * z) - a) / (b - a)))
        gmsh.model.mesh.generate(3)
        _, coords, _ = gmsh.model.mesh.getNodes()
        _, _, enodes = gmsh.model.mesh.getElements(3)
    finally:
        gmsh.finalize()
    p = coords.reshape(-1, 3)
    t = enodes[0].astype(np.int64).reshape(-1, 4) - 1
    return MeshTet(p.T.copy(), t.T.copy())


def lame_sphere_error(nu, size=0.4, md=False, taylor_hood=False):
    """Max relative radial-displacement error of the thick sphere a=1, b=2 under internal pressure p:
    u(r) = p a^3 / (E (b^3 - a^3)) [(1 - 2 nu) r + (1 + nu) b^3 / (2 r^2)].
    Symmetry planes of the octant: u_n = 0. Checked at vertices, which lie on the true spheres."""
    from skfem import FacetBasis, LinearForm

    a, b, E, p = 1.0, 2.0, 1.0, 1.0
    mesh = _octant_shell(a, b, size)
    nodes, tets, G, W, basis = p2_data(mesh)
    mu, lam = lame_params(E, nu, len(tets))
    inner = mesh.facets_satisfying(lambda x: np.linalg.norm(x, axis=0) < a + 1e-6, boundaries_only=True)
    fb = FacetBasis(mesh, ElementTetP2(), facets=inner, intorder=4)
    f = np.zeros(3 * len(nodes))
    for i in range(3):
        form = LinearForm(lambda v, w, i=i: p * w.x[i] / np.linalg.norm(w.x, axis=0) * v)
        f[i::3] = form.assemble(fb)
    fixed = np.concatenate([3 * np.flatnonzero(np.abs(nodes[:, i]) < 1e-9) + i for i in range(3)])
    u, _ = solve_linear(tets, len(nodes), G, W, mu, lam, fixed, np.zeros_like(f), f, md, basis if taylor_hood else None)
    r = np.linalg.norm(nodes, axis=1)
    ur = np.einsum("ij,ij->i", u.reshape(-1, 3), nodes / r[:, None])
    exact = p * a**3 / (E * (b**3 - a**3)) * ((1 - 2 * nu) * r + (1 + nu) * b**3 / (2 * r**2))
    vertices = np.arange(mesh.nvertices)  # on the true spheres; edge nodes sit on chords
    return float(np.abs(ur - exact)[vertices].max() / exact.max())


def newton_with_one_uphill_step(p, monkeypatch, spoil):
    """Newton from a perturbed equilibrium of `p` (1 mm at 4 deg, the guide already in place, so every step
    must pass Armijo), with the first correction for which spoil(cache.factor) holds turned uphill.
    Returns (u, g, stats, final factor, whether a step was spoiled)."""
    import fem_offline.fe.newton as nt
    from fem_offline.fe.solve import solve_case

    u_ref, _ = solve_case(p, 1.0, 4.0)
    g = u_ref.ravel().copy()
    start = g.copy()
    start[p.free] += 1e-3 * np.random.default_rng(0).standard_normal(len(p.free))
    solve, spoiled = nt._solve_linearised, []

    def uphill_once(problem, cache, K, rhs, stats):
        du, stats = solve(problem, cache, K, rhs, stats)
        if spoil(cache.factor) and not spoiled:
            spoiled.append(True)
            return -du, stats  # every backtrack then fails Armijo
        return du, stats

    monkeypatch.setattr(nt, "_solve_linearised", uphill_once)
    cache = nt.FactorCache()
    u, stats = nt.newton(p, start, g, cache)
    return u, g, stats, cache.factor, bool(spoiled)
