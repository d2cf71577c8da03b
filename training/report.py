"""Markdown report laid out like the paper's Table 3."""

from __future__ import annotations


from contracts.model import CaseErrors, ModelManifest

# The paper's Table 3: its worst held-out errors and its training time, which the report sets ours beside.
PAPER_TABLE3 = {"e_nn_mm": 0.03, "alpha_deg": 0.01, "e_r_percent": 1.41, "train_minutes": 38.5}


def _rows(rows: list[CaseErrors]) -> list[str]:
    return [
        f"| {i} | {r.displacement_mm:.3f} | {r.angle_deg:.3f} | {r.e_nn_mm:.4f} | {r.alpha_deg:.3f} | "
        f"{r.e_r_percent:.3f} | {r.mean_mm:.5f} | {r.p99_mm:.4f} | {r.max_displacement_mm:.2f} |"
        for i, r in enumerate(rows, 1)
    ]


def table3_markdown(manifest: ModelManifest, paper: dict) -> str:
    m = manifest.metrics
    head = ["| Sample | X_disp (mm) | β (°) | e_NN (mm) | α (°) | e_r (%) | mean (mm) | p99 (mm) | max |u| (mm) |",
            "|---|---|---|---|---|---|---|---|---|"]
    s = m.table3_summary
    lines = [
        f"# Model `{manifest.name}`: held-out accuracy",
        "",
        f"Scene `{manifest.scene.name}` (sha256 {manifest.scene.sha256[:12]}), "
        f"{manifest.mesh.n_nodes} nodes, {manifest.mesh.n_tets} quadratic tets. "
        f"PCA rank {manifest.pca.rank} (energy {manifest.pca.energy:.8f}); "
        f"MLP {manifest.network.depth}x{manifest.network.width} tanh, "
        f"trained in {manifest.timing.train_seconds:.1f} s on {manifest.network.n_train} snapshots.",
        "",
        "Errors of the exported float32 ONNX model against the FE solution on this model's own mesh, over all "
        "nodes: the surrogate's error alone. They leave out the FE discretisation error of that mesh (the distance "
        "to the converged physics)" + (", which this manifest does not record. " if _no_fe_band(manifest) else
                                        "; \"End to end\" below adds it. ") +
        f"e_NN: max nodal error; α: max angle between displacement vectors over nodes moving more than "
        f"{m.angle_floor_mm} mm; e_r: eq. 2, max component error / max component displacement.",
        "",
        "## The paper's five left-out samples (Table 3)",
        "",
        *head, *_rows(m.table3),
        "",
        f"Worst: e_NN {s.e_nn_mm:.4f} mm, α {s.alpha_deg:.3f}°, e_r {s.e_r_percent:.3f} %. "
        f"Paper: e_NN {paper['e_nn_mm']} mm, α {paper['alpha_deg']}°, e_r {paper['e_r_percent']} %, "
        f"training {paper['train_minutes']} min.",
    ]
    if manifest.envelope_cut is not None:
        c = manifest.envelope_cut
        dropped = ", ".join(f"{d:g} mm / {a:g}°" for d, a in c.dropped_test_cases) or "none"
        lines += ["", "## Envelope cut: where the sweep stops being a deformation", "",
                  f"The sweep covers {c.sweep_envelope.displacement_mm[0]:g} to "
                  f"{c.sweep_envelope.displacement_mm[1]:g} mm, but {c.n_inverted} of its snapshots turn an element "
                  f"inside out (det(I + ∇u) ≤ 0, min {c.min_det_f:.3g}). This model was trained on, and answers for, 0 "
                  f"to {c.valid_up_to_mm:g} mm only: {c.n_excluded} snapshots beyond it were left out. Held-out cases "
                  f"beyond it, not evaluated: {dropped}; off-grid cases beyond it: {c.n_dropped_offgrid}."]
    if m.offgrid_summary:
        o = m.offgrid_summary
        lines += ["", f"## Off-grid cases ({o.n_cases}, random inside the envelope, solved by `fem_offline cases`)", "",
                  *head, *_rows(m.offgrid), "",
                  f"Worst: e_NN {o.e_nn_mm:.4f} mm, α {o.alpha_deg:.3f}°, e_r {o.e_r_percent:.3f} %."]
    lines += ["", f"ONNX (float32) vs float64 numpy reference: max {m.onnx_vs_float64_max_abs_mm:.2e} mm.", ""]
    lines += _accuracy_lines(manifest)
    lines += _material_lines(manifest)
    return "\n".join(lines)


def _mm(x: float | None) -> str:
    return "not measured" if x is None else f"{x:.4f}"


def _accuracy_lines(manifest: ModelManifest) -> list[str]:
    """The end-to-end table: surrogate + FE discretisation, per region, and what it is measured against."""
    acc = manifest.accuracy
    lines = ["## End to end: against the converged physics", "", f"Measured against {acc.reference}.", "",
             "| region | surrogate vs its FE (mm) | FE discretisation (mm) | end-to-end bound (mm) |",
             "|---|---|---|---|"]
    for name, r in acc.regions.items():
        lines.append(f"| {name} | {r.surrogate_mm:.4f} | {_mm(r.fe_discretisation_mm)} | {_mm(r.end_to_end_mm)} |")
    return lines + [""]


def _no_fe_band(manifest) -> bool:
    """True when the model states no FE discretisation error (fitted without --fe-error)."""
    acc = manifest.accuracy
    return acc is None or all(r.fe_discretisation_mm is None for r in acc.regions.values())


def _material_lines(manifest: ModelManifest) -> list[str]:
    """The material inputs (ranges, default std) and the first-order material model's check against fresh FE."""
    info = manifest.materials
    if info is None:
        return []
    lines = ["## Material inputs", "", f"Each input is {info.parameter}; the answer is first order in it.", "",
             "| tissue | nominal E (kPa) | range (kPa) | default std (%) | source |", "|---|---|---|---|---|"]
    for m in info.inputs:
        lines.append(f"| {m.tissue} | {m.nominal_youngs_kpa:g} | {m.youngs_kpa_range[0]:g} to "
                     f"{m.youngs_kpa_range[1]:g} | {m.std_percent:g} | {m.source} |")
    acc = info.accuracy
    if acc is None:
        return lines + ["", "The first-order material model is not checked against fresh FE solves for this model "
                        "(`python -m training material-check`).", ""]
    lines += ["", f"Checked against {acc.reference}. End to end: the model against the fresh solves plus the FE "
              "discretisation error of this mesh (above), where measured.", "",
              "| region | first order vs fresh FE (mm) | model vs fresh FE (mm) | end to end (mm) |",
              "|---|---|---|---|"]
    for k, r in acc.regions.items():
        fe = manifest.accuracy.regions[k].fe_discretisation_mm if k in manifest.accuracy.regions else None
        lines.append(f"| {k} | {r.first_order_mm:.4f} | {r.model_mm:.4f} | "
                     f"{_mm(None if fe is None else r.model_mm + fe)} |")
    return lines + [""]


def design_markdown(manifest: ModelManifest, checked: dict | None) -> str:
    """A design model's report: what it was fitted on, and its errors against the held-out design's fresh FE."""
    lines = [f"# Model `{manifest.name}`: a design model over the stiffness box", "",
             f"Scene `{manifest.scene.name}` (sha256 {manifest.scene.sha256[:12]}), {manifest.mesh.n_nodes} nodes, "
             f"{manifest.mesh.n_tets} quadratic tets. PCA rank {manifest.pca.rank}; MLP 1x{manifest.network.width} "
             f"tanh on (d, beta, theta), fitted to values and theta-derivatives in {manifest.timing.train_seconds:.1f} "
             f"s on {manifest.network.n_train} snapshots.", ""]
    if checked is None:
        return "\n".join([*lines, "Not checked against held-out FE (no `--held-out` design).", ""])
    lines += [f"Against fresh FE at {checked['n_points']} held-out material points x (-beta, beta) "
              f"({checked['n_snapshots']} snapshots; the surrogate's error alone, on its own mesh):", "",
              "| region | every push (mm) | largest push (mm) |", "|---|---|---|"]
    lines += [f"| {k} | {v['all_mm']:.4f} | {v['largest_push_mm']:.4f} |" for k, v in checked["regions"].items()]
    if checked["unfinished"]:
        lines += ["", f"Held-out points whose paths stopped short (what they reached is compared): "
                  f"{', '.join(checked['unfinished'])}."]
    return "\n".join([*lines, ""])
