"""Training's side of the material inputs: the S rows a model is fitted on, the manifest's inputs, and the check
of the first-order material model against fresh FE solves at held-out material points.

A material sweep stores S_i = du/d ln E_i at every snapshot (contracts.sweep). Like u, S_i vanishes at rest and
grows with the push, so it is fitted as S_i / d; the PCA basis is fitted on the u / d and every S_i / d row
together, and the network gives (1 + m) x rank coefficients (material_graph.py decodes them).

The check (`python -m training material-check --model M --cases DIR`) reads the cases `fem_offline
material-cases` solved: at a few guide positions, the nominal u0 and S_i, and fresh FE solves at material points
theta (each tissue at both ends of its range, and two corners where they alternate between their ends). Per region it
records the largest error of the first-order model u0 + sum S_i theta_i against the fresh solve (the material part
alone), and of the served ONNX model against it (surrogate + first order), into the manifest's materials.accuracy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contracts.materials import (PARAMETER, MaterialAccuracy, MaterialInput, MaterialRegionAccuracy, MaterialsInfo,
                                 sensitivity_key)
from contracts.scene import Scene

CASE_GLOB = "material_*.npz"


def sensitivity_rows(sensitivity: dict[str, np.ndarray] | None, inputs: np.ndarray,
                     keep: np.ndarray) -> list[np.ndarray]:
    """Per material tissue the rows S_i / d (n_kept, 3 n_nodes) of the kept snapshots (as training_set keeps u / d)."""
    if not sensitivity:
        return []
    d = inputs[keep, :1]
    return [s[keep].reshape(int(keep.sum()), -1) / d for s in sensitivity.values()]


def theta_rms(info: MaterialsInfo) -> np.ndarray:
    """Per tissue the root mean square of theta = ln(E / E_nominal) over its declared range (uniform in theta):
    the weight of its S_i in the fit, so the loss is the mean squared error of u + sum_i theta_i S_i over the
    ranges (u and the S_i errors add in quadrature for independent, centred theta_i)."""
    out = []
    for m in info.inputs:
        lo, hi = (np.log(e / m.nominal_youngs_kpa) for e in m.youngs_kpa_range)
        out.append(np.sqrt((lo * lo + lo * hi + hi * hi) / 3))
    return np.array(out)


def materials_info(scene: Scene) -> MaterialsInfo | None:
    """The manifest's material inputs from a sweep's scene, in the scene's order; None without [materials]."""
    if not scene.materials:
        return None
    inputs = []
    for name, m in scene.materials.items():
        t = scene.tissues[name]
        inputs.append(MaterialInput(tissue=name, nominal_youngs_kpa=t.youngs, youngs_kpa_range=m.youngs_kpa_range,
                                    std_percent=m.std_percent, poisson=t.poisson, density_kg_m3=t.density_kg_m3,
                                    source=m.source))
    return MaterialsInfo(parameter=PARAMETER, inputs=inputs)


def read_material_cases(folder: str | Path, tissues: list[str]) -> list[dict]:
    """The cases of a `fem_offline material-cases` folder: guide (2,), u0 (n_nodes, 3), S (m, n_nodes, 3) and theta
    (p, m) in `tissues` order (a tissue the case does not vary: theta 0), and the fresh solves (p, n_nodes, 3)."""
    files = sorted(Path(folder).glob(CASE_GLOB))
    if not files:
        raise ValueError(f"--cases: no {CASE_GLOB} in {folder}")
    cases = []
    for f in files:
        with np.load(f) as z:
            varied = [str(t) for t in z["tissues"]]
            if set(varied) - set(tissues):
                raise ValueError(f"--cases: {f.name} varies {varied}, the model takes {tissues}")
            theta = np.zeros((len(z["theta"]), len(tissues)))  # a tissue the case does not vary stays nominal
            sens = np.zeros((len(tissues), *z["displacement"].shape))
            for i, t in enumerate(tissues):
                if t in varied:
                    theta[:, i], sens[i] = z["theta"][:, varied.index(t)], z[sensitivity_key(t)]
            failures = z["failures"] if "failures" in z.files else np.array([""] * len(theta))
            cases.append({"guide": np.array([float(z["displacement_mm"]), float(z["angle_deg"])]),
                          "u0": z["displacement"], "sens": sens, "theta": theta, "fresh": z["fresh"],
                          "failures": [str(f) for f in failures]})
    return cases


def first_order_errors(cases: list[dict], session, node_sets: dict, regions: tuple[str, ...]) -> MaterialAccuracy:
    """Largest nodal error (mm) per region over every case and material point: the first-order FE model and the
    ONNX model (inputs guide, materials) against the fresh FE solves."""
    worst = {r: [0.0, 0.0] for r in regions}
    n, unsolved = 0, []
    for c in cases:
        for theta, fresh, failure in zip(c["theta"], c["fresh"], c["failures"]):
            if failure:
                unsolved.append(f"{c['guide'][0]:g} mm / {c['guide'][1]:g} deg, theta {np.round(theta, 3).tolist()}: "
                                f"{failure}")
                continue
            linear = c["u0"] + np.einsum("m,mnk->nk", theta, c["sens"])
            model = session.run(["displacement"], {"guide": c["guide"][None].astype(np.float32),
                                                   "materials": theta[None].astype(np.float32)})[0][0]
            errors = (np.linalg.norm(linear - fresh, axis=1), np.linalg.norm(model - fresh, axis=1))
            for r in regions:
                ids = node_sets.get(r, slice(None)) if r != "all_nodes" else slice(None)
                worst[r] = [max(w, float(e[ids].max())) for w, e in zip(worst[r], errors)]
            n += 1
    points = ", ".join(f"{c['guide'][0]:g} mm / {c['guide'][1]:g} deg" for c in cases)
    reference = (f"fresh FE solves on the model's mesh at {n} material points (each tissue at both ends of its "
                 "declared range, then the two corners where the tissues alternate between their ends), at the guide "
                 f"positions {points}: the first-order model u0 + sum_i "
                 "S_i ln(E_i/E_i0) from the nominal state's sensitivities, and the ONNX model, against them")
    if not n:
        raise ValueError("--cases: the FE found no equilibrium at any material point; there is nothing to compare")
    if unsolved:
        reference += (f"; at {len(unsolved)} more points the FE found no equilibrium, so they are not compared "
                      "(materials.accuracy.unsolved)")
    return MaterialAccuracy(reference=reference, n_points=n, unsolved=unsolved, regions={
        r: MaterialRegionAccuracy(first_order_mm=a, model_mm=b) for r, (a, b) in worst.items()})


def stamp(model: Path, cases: Path):
    """A material model folder's manifest (and report.md) stamped with its check against the cases' fresh FE
    solves, without refitting (as fit.restamp): the ONNX graph and the mesh stay as they are."""
    from contracts.files import atomic_write_text, sha256
    from contracts.model import onnx_session, read_model_folder

    from .metrics import REGIONS
    from .report import PAPER_TABLE3, table3_markdown

    current = read_model_folder(model)
    info = current.manifest.materials
    if info is None:
        raise ValueError(f"--model: {model} takes no material inputs (its sweep's scene has no [materials])")
    found = read_material_cases(cases, info.tissues)
    if any(c["u0"].shape != current.mesh.nodes.shape for c in found):
        raise ValueError(f"--cases: {cases} holds cases on another mesh than {model}'s")
    accuracy = first_order_errors(found, onnx_session(Path(model) / "model.onnx"), current.regions, REGIONS)
    manifest = current.manifest.model_copy(update={"materials": info.model_copy(update={"accuracy": accuracy})})
    atomic_write_text(Path(model) / "report.md", table3_markdown(manifest, PAPER_TABLE3))
    manifest = manifest.model_copy(update={"files": {**manifest.files, "report.md": sha256(Path(model) / "report.md")}})
    atomic_write_text(Path(model) / "manifest.json", manifest.model_dump_json(indent=2) + "\n")
    return manifest


# Room for float32 round-off only: two graphs that compute the same fields in another operation order differ
# by far less (the rebuild of models/default: CHANGELOG), a graph that computes other fields by far more.
REGRAPH_TOLERANCE_MM = 1e-4


def regraph(model: Path) -> tuple[float, float]:
    """A material model folder's graph rebuilt by today's build_material_graph from its own weights (network
    layers, basis and mean, read from model.onnx), without refitting; returns the largest |difference| (mm) of
    displacement and of displacement_std between the old and the new graph, over the sweep's guide grid at the
    nominal materials and at every corner of the ranges with the default std. Refused, and nothing written, when
    either passes REGRAPH_TOLERANCE_MM. The manifest's accuracy was measured with the old graph; this bound says
    the new one answers the same."""
    import itertools

    from contracts.files import atomic_write_bytes, atomic_write_text, sha256
    from contracts.model import onnx_session, read_model_folder

    from .export import read_weights
    from .material_graph import build_material_graph

    current = read_model_folder(model)
    info = current.manifest.materials
    if info is None:
        raise ValueError(f"--model: {model} takes no material inputs; only a material model's graph is rebuilt")
    old_bytes = (Path(model) / "model.onnx").read_bytes()
    layers, pca, dtype = read_weights(old_bytes)
    new_bytes = build_material_graph(layers, pca, len(info.inputs), dtype=dtype).SerializeToString()

    sweep = current.manifest.scene.spec.sweep
    d = np.arange(0.0, sweep.displacement_max_mm + 1e-9, max(sweep.displacement_step_mm, 1.0))
    a = np.arange(sweep.angle_min_deg, sweep.angle_max_deg + 1e-9, max(sweep.angle_step_deg, 2.5))
    guides = np.array([(x, y) for x in d for y in a], dtype=np.float32)
    bounds = [np.log(np.asarray(m.youngs_kpa_range) / m.nominal_youngs_kpa) for m in info.inputs]
    thetas = [np.zeros(len(bounds)), *map(np.array, itertools.product(*bounds))]
    sigma = np.array([m.std_percent / 100 for m in info.inputs], dtype=np.float32)  # std(E) / E, as served
    old, new = onnx_session(old_bytes), onnx_session(new_bytes)
    du = dstd = 0.0
    for theta in thetas:
        feed = {"guide": guides, "materials": np.tile(theta.astype(np.float32), (len(guides), 1)),
                "materials_std": np.tile(sigma, (len(guides), 1))}
        (u0, s0), (u1, s1) = old.run(None, feed), new.run(None, feed)
        du, dstd = max(du, float(np.abs(u1 - u0).max())), max(dstd, float(np.abs(s1 - s0).max()))
    if max(du, dstd) > REGRAPH_TOLERANCE_MM:
        raise ValueError(f"--model: the rebuilt graph differs from {model}'s by {du:.3g} mm (displacement) and "
                         f"{dstd:.3g} mm (std), over {REGRAPH_TOLERANCE_MM:g} mm; not written")
    atomic_write_bytes(Path(model) / "model.onnx", new_bytes)
    manifest = current.manifest.model_copy(update={"files": {**current.manifest.files,
                                                             "model.onnx": sha256(Path(model) / "model.onnx")}})
    atomic_write_text(Path(model) / "manifest.json", manifest.model_dump_json(indent=2) + "\n")
    return du, dstd
