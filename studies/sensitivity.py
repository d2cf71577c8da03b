"""Which tissue's stiffness moves the answer where: FE sensitivities du/d ln E on the served model's mesh.

    python -m studies sensitivity [--model models/default] [--scene fem_offline/scenes/default.toml] \
        [--out runs/sensitivity] [--publish]

On the model's own mesh with its scene's physics (the tip in contact, Taylor-Hood), paths at beta = 0 and
10 deg (-10 mirrors 10) are load-stepped to 10 mm; at 2.5, 5, 7.5 and 10 mm the sensitivity S_i = du/d ln E_i
of each soft tissue is one solve with the converged tangent (fem_offline.fe.sensitivity). A +-25 % error
in E_i moves the answer by about |S_i| ln 1.25: the table gives its largest size at the eight markers, on
the prostate surface and at a lesion at the prostate's centre. At 10 mm, beta = 0, fresh FE solves with
each E_i x 1.25 check that first-order change, and solves with nu = 0.49 and 0.499 give the effect of the
Poisson ratio against 0.495. Every path is saved under --out when done; a rerun skips finished paths.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from contracts.interpolate import PointLocator, interpolate
from contracts.model import read_model_folder
from studies import results

RECORD_MM = (2.5, 5.0, 7.5, 10.0)
ANGLES_DEG = (0.0, 10.0)
FACTOR = 1.25
POISSONS = (0.49, 0.499)
REGIONS = ("markers", "prostate_surface", "lesion")


def _problem(scene, mesh):
    from fem_offline.fe.problem import build_problem

    return build_problem(scene, mesh)


def _variant(scene, *, factors: dict[str, float] | None = None, poisson: float | None = None):
    """The scene with some tissues' E scaled, or every tissue's nu set."""
    tissues = {}
    for name, t in scene.tissues.items():
        update = {"youngs_kpa": t.youngs * (factors or {}).get(name, 1.0), "shear_wave_speed_m_s": None}
        if poisson is not None:
            update["poisson"] = poisson
        tissues[name] = t.model_copy(update=update)
    return scene.model_copy(update={"tissues": tissues})


class Probe:
    """The three places a user asks about: marker nodes, prostate-surface nodes and the prostate's centre."""

    def __init__(self, mesh, centre_mm):
        self.markers = np.asarray(mesh.node_sets["markers"])
        self.surface = np.asarray(mesh.node_sets["prostate_surface"])
        locator = PointLocator(mesh.nodes, mesh.tets[:, :4])
        tet, bary = locator.locate(np.asarray([centre_mm], float))
        if tet[0] < 0:
            raise ValueError(f"the lesion point {centre_mm} is outside the mesh")
        self._tet10, self._bary = mesh.tets[tet], bary

    def sizes(self, field: np.ndarray) -> dict[str, float]:
        """Largest |field| (mm) per region; field (n_nodes, 3)."""
        lesion = interpolate(field[self._tet10], self._bary)
        return {"markers": float(np.linalg.norm(field[self.markers], axis=1).max()),
                "prostate_surface": float(np.linalg.norm(field[self.surface], axis=1).max()),
                "lesion": float(np.linalg.norm(lesion, axis=1).max())}


def sensitivity_path(problem, angle_deg: float, out: Path) -> Path:
    """Solve one path, saving u and every soft tissue's S at RECORD_MM to `out` (.npz); skip it if done."""
    from fem_offline.fe.continuation import solve_path
    from fem_offline.fe.sensitivity import sensitivities, stiffened

    if out.exists():
        return out
    models = stiffened(problem)
    saved, t0 = {}, time.perf_counter()
    for d, u, _, state in solve_path(problem, RECORD_MM, angle_deg, with_state=True):
        loaded = problem.at_guide(d, angle_deg, state.multipliers)
        saved[f"u_{d:g}"] = u
        for name, s in sensitivities(models, loaded, state.u).items():
            saved[f"S_{name}_{d:g}"] = s
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out.with_suffix(".tmp.npz"), seconds=time.perf_counter() - t0, **saved)
    out.with_suffix(".tmp.npz").rename(out)
    return out


def end_state(problem, angle_deg: float, d_mm: float, out: Path) -> np.ndarray:
    """u (n_nodes, 3) at (d_mm, angle_deg), load-stepped from rest; saved to `out` and reused."""
    from fem_offline.fe.continuation import solve_path

    if not out.exists():
        (_, u, _), = solve_path(problem, [d_mm], angle_deg)
        out.parent.mkdir(parents=True, exist_ok=True)
        np.save(out.with_suffix(".tmp.npy"), u)
        out.with_suffix(".tmp.npy").rename(out)
    return np.load(out)


def _table(paths: dict[float, Path], probe: Probe, tissues) -> list[dict]:
    rows = []
    for angle, path in paths.items():
        with np.load(path) as z:
            for d in RECORD_MM:
                total = sum(z[f"S_{n}_{d:g}"] for n in tissues)
                largest = max(np.abs(z[f"S_{n}_{d:g}"]).max() for n in tissues)
                for name in tissues:
                    change = probe.sizes(z[f"S_{name}_{d:g}"] * np.log(FACTOR))
                    rows.append({"displacement_mm": d, "angle_deg": angle, "tissue": name,
                                 **{f"{k}_mm": round(v, 4) for k, v in change.items()},
                                 "sum_over_tissues_rel": float(np.abs(total).max() / largest)})
    return rows


def run(model: Path, scene_path: Path, out: Path) -> dict:
    from fem_offline.geometry.regions import build_node_sets
    from fem_offline.scene import load_scene
    from fem_offline.fe.sensitivity import soft_tissues

    folder = read_model_folder(model)
    scene = load_scene(scene_path)
    mesh = build_node_sets(folder.mesh, scene)
    probe = Probe(mesh, scene.phantom.prostate_center_mm)
    base = _problem(scene, mesh)
    tissues = soft_tissues(base)
    jobs = [("path", a) for a in ANGLES_DEG] + [("E", n) for n in tissues] + [("nu", v) for v in POISSONS]
    paths, fe_check, poisson = {}, [], []
    for kind, what in tqdm(jobs, desc="sensitivity paths", unit="path"):
        if kind == "path":
            paths[what] = sensitivity_path(base, what, out / f"path_beta{what:g}.npz")
            continue
        with np.load(paths[0.0]) as z:
            u0 = z["u_10"]
            s = {n: z[f"S_{n}_10"] for n in tissues}
        if kind == "E":
            u = end_state(_problem(_variant(scene, factors={what: FACTOR}), mesh), 0.0, 10.0,
                          out / f"E_{what}_x{FACTOR:g}.npy")
            fe, lin = probe.sizes(u - u0), probe.sizes(s[what] * np.log(FACTOR))
            miss = probe.sizes(u - u0 - s[what] * np.log(FACTOR))
            fe_check.append({"tissue": what, "factor": FACTOR, "fe_change_mm": fe, "first_order_change_mm": lin,
                             "first_order_error_mm": miss})
        else:
            try:
                u = end_state(_problem(_variant(scene, poisson=what), mesh), 0.0, 10.0, out / f"nu_{what:g}.npy")
                poisson.append({"poisson": what, "change_mm": probe.sizes(u - u0)})
            except Exception as exc:  # noqa: BLE001 - a solver that does not hold at nu -> 0.5 is a result
                poisson.append({"poisson": what, "failed": str(exc)[:300]})
    return {"kind": "sensitivity", "model": str(model), "scene": str(scene_path), "factor": FACTOR,
            "mesh": {"n_tets": len(mesh.tets), "n_nodes": len(mesh.nodes)},
            "youngs_kpa": {n: scene.tissues[n].youngs for n in tissues},
            "nominal_poisson": scene.tissues["prostate"].poisson, "lesion_mm": list(scene.phantom.prostate_center_mm),
            "rows": _table(paths, probe, tissues), "fe_check": fe_check, "poisson": poisson}


def report(data: dict) -> str:
    """The result as Markdown: the +-25 % table at 10 mm, the FE check, the Poisson ratio, and the plot."""
    f = data["factor"]
    out = ["# Sensitivity to the tissues' stiffness", "",
           f"How far the answer moves when one tissue's E is off by {100 * (f - 1):.0f} % (first order, |S_i| ln "
           f"{f:g}), largest over the region, on `{data['model']}`'s mesh ({data['mesh']['n_tets']:,} tets) with its "
           "scene's physics.", "", "![change per tissue against d](sensitivity.png)", "",
           "| d (mm) | beta (deg) | tissue | markers (mm) | prostate surface (mm) | lesion at the centre (mm) |",
           "|---|---|---|---|---|---|"]
    out += [f"| {r['displacement_mm']:g} | {r['angle_deg']:g} | {r['tissue']} | {r['markers_mm']:.3f} | "
            f"{r['prostate_surface_mm']:.3f} | {r['lesion_mm']:.3f} |"
            for r in data["rows"] if r["displacement_mm"] in (5.0, 10.0)]
    out += ["", f"**Against fresh FE** at 10 mm, beta = 0, each E x {f:g} solved anew (the first-order change's error "
            "is what a model using the sensitivities adds):", "",
            "| tissue | FE change, markers (mm) | first order (mm) | first-order error, markers (mm) | surface (mm) | "
            "lesion (mm) |", "|---|---|---|---|---|---|"]
    out += [f"| {c['tissue']} | {c['fe_change_mm']['markers']:.3f} | {c['first_order_change_mm']['markers']:.3f} | "
            f"{c['first_order_error_mm']['markers']:.4f} | {c['first_order_error_mm']['prostate_surface']:.4f} | "
            f"{c['first_order_error_mm']['lesion']:.4f} |" for c in data["fe_check"]]
    out += ["", f"**The Poisson ratio** at 10 mm, beta = 0, every tissue's nu against {data['nominal_poisson']:g}:", "",
            "| nu | markers (mm) | prostate surface (mm) | lesion (mm) |", "|---|---|---|---|"]
    for p in data["poisson"]:
        c = p.get("change_mm")
        out.append(f"| {p['poisson']:g} | " + (" | ".join(f"{c[k]:.3f}" for k in REGIONS) if c else
                                                f"the solver did not hold: {p['failed'][:120]} | | ") + " |")
    worst = max(r["sum_over_tissues_rel"] for r in data["rows"])
    out += ["", f"Scaling every E together leaves u unchanged: the four sensitivities sum to at most {worst:.1%} of "
            "the largest, the compliance of the contact penalty (exactly zero with the glued patch, "
            "tests/fem_offline/fe/test_sensitivity.py)."]
    return "\n".join(out) + "\n"


def plot(data: dict, path: Path) -> None:
    """|change| at E x factor against d, per tissue and region (beta 0 solid, 10 dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    for ax, region in zip(axes, REGIONS):
        for i, tissue in enumerate(data["youngs_kpa"]):
            for angle, style in zip(ANGLES_DEG, ("-", "--")):
                rows = [r for r in data["rows"] if r["tissue"] == tissue and r["angle_deg"] == angle]
                ax.plot([r["displacement_mm"] for r in rows], [r[f"{region}_mm"] for r in rows], style, color=f"C{i}",
                        marker="o", label=f"{tissue}, beta {angle:g}")
        ax.set_title(region.replace("_", " "))
        ax.set_xlabel("guide displacement d (mm)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"|change| at E x {data['factor']:g} (mm)")
    axes[-1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m studies sensitivity", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=Path("models/default"), help="the model whose mesh is solved on")
    ap.add_argument("--scene", type=Path, default=Path("fem_offline/scenes/default.toml"), help="its scene")
    ap.add_argument("--out", type=Path, default=Path("runs/sensitivity"), help="the paths' checkpoints")
    ap.add_argument("-v", "--verbose", action="store_true", help="log solver progress")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    try:
        data = run(args.model, args.scene, args.out)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    data["report_md"] = report(data)
    path = results.write("sensitivity", data, publish=args.publish)
    plot(data, path.with_suffix(".png"))
    for row in data["rows"]:
        if row["displacement_mm"] == 10.0:
            print(f"10 mm, beta {row['angle_deg']:g}: {row['tissue']:<12} E x {FACTOR:g}: markers "
                  f"{row['markers_mm']:.3f} mm, surface {row['prostate_surface_mm']:.3f}, lesion "
                  f"{row['lesion_mm']:.3f} (first order)")
    for c in data["fe_check"]:
        print(f"FE check {c['tissue']:<12}: markers {c['fe_change_mm']['markers']:.3f} mm (first order "
              f"{c['first_order_change_mm']['markers']:.3f}, off by {c['first_order_error_mm']['markers']:.4f})")
    for p in data["poisson"]:
        said = f"markers {p['change_mm']['markers']:.3f} mm vs 0.495" if "change_mm" in p else p["failed"]
        print(f"nu {p['poisson']}: " + said)
    print(f"wrote {path}")
    return 0
