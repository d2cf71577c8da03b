"""Markdown from measured results: the README's generated tables and the docs site's result blocks.

Every block names where its numbers come from: the model manifest, or a committed result under
docs/results/ with its provenance (command, commit, date, machine). A block whose result was measured
at a commit older than the last change to the code it describes says so.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

from studies.results import DOCS_RESULTS, ROOT

MANIFEST = ROOT / "models" / "default" / "manifest.json"
BENCH_SERVICE = "bench_service"
# The code a result describes, by the study's name prefix: a result older than the last commit that
# touched these paths is flagged as possibly stale. The FE studies describe fem_offline; the model's
# accuracy and the trade-off also training; the service benchmark the service.
CODE_OF = (("bench_service", ("service", "models/default")),
           ("fe_error", ("fem_offline", "training", "models/default")),
           ("tradeoff", ("fem_offline", "training")), ("sweep_density", ("fem_offline", "training")),
           ("design", ("fem_offline", "training")),
           ("", ("fem_offline",)))
REGIONS = (("markers", "markers"), ("interior", "interior points"), ("prostate_surface", "prostate surface"),
           ("all_nodes", "every node"))


def _git(*args: str) -> str | None:
    """A git command's stdout in the repository, or None outside a checkout or when git fails."""
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return out.stdout.strip()


def code_paths(name: str) -> tuple[str, ...]:
    """The folders whose code the result NAME describes (CODE_OF, first matching prefix)."""
    return next(paths for prefix, paths in CODE_OF if name.startswith(prefix))


def stale_note(commit: str, paths: tuple[str, ...]) -> str:
    """A warning when `paths` changed in a commit after `commit`; "" when they did not or git cannot tell."""
    commit = commit.removesuffix("-dirty")
    if not re.fullmatch(r"[0-9a-f]{7,40}", commit) or _git("cat-file", "-e", f"{commit}^{{commit}}") is None:
        return ""
    later = _git("log", "-1", "--format=%h %cs", f"{commit}..HEAD", "--", *paths)
    if not later:
        return ""
    return (f"!!! warning \"Older than the code\"\n    Measured at {commit[:10]}; {', '.join(paths)} "
            f"changed since (last in {later}). The figures describe the code as it was then.\n")


def provenance_line(result: dict) -> str:
    """One line: the command that made the result, its commit, date and machine."""
    p = result.get("provenance")
    if not p:
        return "*No provenance recorded.*"
    m = p.get("machine", {})
    machine = f"{m.get('cores', '?')} cores, {m.get('cpu_model', 'unknown CPU')}"
    if m.get("load_1min") is not None:
        machine += f", load {m['load_1min']}"
    note = f" ({p['note']})" if p.get("note") else ""
    mnote = f"; {m['note']}" if m.get("note") else ""
    return (f"*Measured by* `{p['command']}` *at commit* `{str(p['commit'])[:10]}` *on {p['date'][:10]}, "
            f"{machine}{mnote}.*{note}")


def load(name: str, folder: Path = DOCS_RESULTS) -> dict | None:
    """docs/results/NAME.json, or None when there is no committed result."""
    path = Path(folder) / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def _mm(x) -> str:
    """Millimetres to 3 decimals (4 below 0.01 mm, so a small surrogate error is not shown as 0.001)."""
    return "—" if x is None else f"{x:.4f}" if abs(x) < 0.01 else f"{x:.3f}"


def accuracy_table(manifest_path: Path = MANIFEST) -> str:
    """The default model's accuracy per region: surrogate vs its own FE, FE vs the converged estimate, end to end;
    for a material model also the model against fresh FE over the declared stiffness ranges, and that end to end."""
    m = json.loads(Path(manifest_path).read_text())
    acc = m["accuracy"]["regions"]
    materials = (m.get("materials") or {}).get("accuracy")
    head = ["region", "surrogate vs its own FE (mm)", "FE vs converged estimate (mm)",
            "end to end, nominal stiffness (mm)"]
    if materials:
        head += ["model vs fresh FE over the stiffness ranges (mm)", "end to end over the ranges (mm)"]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, label in REGIONS:
        if key in acc:
            r = acc[key]
            cells = [label, _mm(r["surrogate_mm"]), _mm(r["fe_discretisation_mm"]), f"**{_mm(r['end_to_end_mm'])}**"]
            if materials and key in materials["regions"]:
                over = max(materials["regions"][key]["model_mm"], r["surrogate_mm"])
                cells += [_mm(over), f"**{_mm(over + r['fe_discretisation_mm'])}**"]
            elif materials:
                cells += ["—", "—"]
            rows.append("| " + " | ".join(cells) + " |")
    resolved = Path(manifest_path).resolve()
    rel = resolved.relative_to(ROOT) if resolved.is_relative_to(ROOT) else manifest_path
    mesh = m["mesh"]
    ranges = (" These are for the scene's exact stiffnesses; a patient's are uncertain, and one tissue's E x 1.25 "
              "moves the markers by up to about 0.3 mm (docs site: Sensitivity to the materials), which this model "
              "cannot take into account.")
    rank = f"PCA rank {m['pca']['rank']}"
    if materials:
        unsolved = materials.get("unsolved") or []
        left = (f"; at {len(unsolved)} more the FE found no equilibrium, so they are not compared (docs site: "
                "Materials as inputs)" if unsolved else "")
        ranges = (f" Over the stiffness ranges: the model against fresh FE solves at {materials['n_points']} material "
                  f"points (`python -m training material-check`{left}). Each answer also carries the std its stiffness "
                  "inputs' uncertainty gives (`std_mm`), which is not in this table.")
        if m["pca"].get("n_primary"):
            rank += f": {m['pca']['n_primary']} for u, {m['pca']['rank'] - m['pca']['n_primary']} for the sensitivities"
    return "\n".join([
        f"Largest error over the region's points and the held-out cases, `{m['name']}` model "
        f"({mesh['n_tets']:,} tets, {mesh['n_nodes']:,} nodes, {rank}, "
        f"{m['network']['depth']}x{m['network']['width']} network). End to end = surrogate + FE: what a user of the "
        "answer faces, against the converged FE estimate." + ranges, "",
        *rows, "", f"*Generated from* `{rel}` *(accuracy.regions; the model built {m['created_utc'][:10]} by* `make "
        "default-model`*) by* `python -m studies readme`. *The FE column comes from "
        "docs/results/fe_error_default.json:* "
        + _provenance_brief(load("fe_error_default"))])


def _provenance_brief(result: dict | None) -> str:
    """`command` at commit, date: the short form of provenance_line for a sentence."""
    if not result or "provenance" not in result:
        return "*no provenance recorded.*"
    p = result["provenance"]
    return f"`{p['command']}` *at* `{str(p['commit'])[:10]}`*, {p['date'][:10]}.*"


def speed_table(folder: Path = DOCS_RESULTS) -> str:
    """The service benchmark's README rows (docs/results/bench_service.json), or a line saying there is none."""
    result = load(BENCH_SERVICE, folder)
    if result is None or not result.get("readme_rows"):
        return ("The service benchmark has no committed result yet (`python -m bench service --publish` "
                "writes docs/results/bench_service.json).")
    rows = ["| request | p50 (ms) | p99 (ms) | requests/s |", "|---|---|---|---|"]
    rows += [f"| {r['what']} | {r['p50_ms']:.2f} | {r['p99_ms']:.2f} | {r['req_s']:,.0f} |"
             for r in result["readme_rows"]]
    return "\n".join([*rows, "", provenance_line(result).replace("*Measured by*", "*Generated from docs/results/"
                      "bench_service.json by* `python -m studies readme`; *measured by*", 1)])


def service_targets_table(folder: Path = DOCS_RESULTS) -> str:
    """The service benchmark's targets (met or not), how many runs each row's median took, and the versions it
    ran with (docs/results/bench_service.json)."""
    result = load(BENCH_SERVICE, folder)
    if result is None or not result.get("targets"):
        return "*The service benchmark has no committed targets yet.*"
    rows = ["| target | measured | met |", "|---|---|---|"]
    rows += [f"| {t['target']} | {t['value']} | {'yes' if t['met'] else '**no**'} |" for t in result["targets"]]
    versions = ", ".join(f"{k} {v}" for k, v in result.get("versions", {}).items()) or "not recorded"
    recorded = isinstance(result.get("load_at_start"), float) and isinstance(result.get("load_at_end"), float)
    load_ = (f"load {result.get('load_at_start', '?'):.2f} at the start, {result.get('load_at_end', '?'):.2f} at the "
             "end" if recorded else "load not recorded")
    runs = result.get("repeats", 1)
    rows += ["", *cpu_table(result.get("cpu", []))]
    return "\n".join([*rows, "", f"Each row is the median of {runs} run(s) of {result.get('duration_s', '?')} s, the "
                      f"configurations taking turns; {load_}. Versions: {versions}.", "", provenance_line(result)])


def cpu_table(cpu: list[dict]) -> list[str]:
    """bench/service_targets.py's cpu_rows as Markdown lines: where the large model's batched requests spend CPU."""
    if not cpu:
        return []
    lines = ["Where the large model's batched requests (8 clients, full binary, batching on) spend CPU, in core-ms "
             "a request; *bound* is what the service would serve with every core it has (and the clients have, "
             "where they share them) busy at that cost, *busy* the served share of it, and served / capacity = "
             "decode / (service + clients on its cores) × busy:", "",
             "| cores | decode alone | service, user + system | clients | clients on the service's cores | bound "
             "(req/s) | served (req/s) | busy | served / capacity |", "|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {c['cores']} | {c['decode_ms']:.2f} | {c['service_user_ms']:.2f} + {c['service_sys_ms']:.2f} | "
              f"{c['client_ms']:.2f} | {'yes' if c['clients_share_cores'] else 'no'} | {c['bound_rps']:,.0f} | "
              f"{c['served_rps']:,.0f} | {c['busy']:.0%} | {c['served_share']:.2f} |" for c in cpu]
    return lines


# --- the README's generated blocks ---------------------------------------------------------------

BLOCKS = {"accuracy": accuracy_table, "speed": speed_table}


def fill(text: str, blocks: dict | None = None) -> str:
    """`text` with each `<!-- generated:NAME -->...<!-- /generated:NAME -->` block rewritten by BLOCKS[NAME]()."""
    blocks = BLOCKS if blocks is None else blocks

    def one(match: re.Match) -> str:
        name = match.group(1)
        return f"<!-- generated:{name} -->\n{blocks[name]()}\n<!-- /generated:{name} -->"

    return re.sub(r"<!-- generated:(\w+) -->.*?<!-- /generated:\1 -->", one, text, flags=re.S)


# --- the docs site's result blocks --------------------------------------------------------------

def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "—" if v is None else str(v)


def flat(d: dict, prefix: str = "") -> dict:
    """Scalar leaves of nested dicts as {"a.b.c": value}; lists are left out (they stay in the JSON)."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flat(v, key + "."))
        elif not isinstance(v, list):
            out[key] = v
    return out


def _is_error(key: str, value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and "mm" in key.rsplit(".", 1)[-1]


def rows_table(rows: list[dict], limit: int = 40, max_cols: int = 12) -> str:
    """Rows as a Markdown table: their identifying top-level scalars, then their millimetre figures
    (nested ones flattened as a.b), up to `max_cols` columns; every other value stays in the JSON."""
    flats = [flat(r) for r in rows]
    ids = [k for k in flats[0] if "." not in k and not _is_error(k, flats[0][k])
           and not str(flats[0][k]).startswith("python ")][:4]
    mm = [k for k in dict.fromkeys(k for f in flats for k in f)
          if _is_error(k, next((f[k] for f in flats if k in f), None))]
    cols = ids + mm[: max_cols - len(ids)]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(_cell(f.get(c)) for c in cols) + " |" for f in flats[:limit]]
    left = len(rows) - limit
    if left > 0 or len(mm) > len(cols) - len(ids):
        out.append(f"\n*More in the JSON{f' ({left} more rows)' if left > 0 else ''}.*")
    return "\n".join(out)


def figures_table(result: dict, limit: int = 30) -> str:
    """A result without rows: its millimetre figures as (quantity, value), nested keys flattened as a.b."""
    figs = [(k, v) for k, v in flat({k: v for k, v in result.items() if k != "provenance"}).items() if _is_error(k, v)]
    if not figs:
        return "Its figures are lists (see the JSON)."
    out = ["| quantity | value |", "|---|---|"] + [f"| {k} | {_cell(v)} |" for k, v in figs[:limit]]
    if len(figs) > limit:
        out.append(f"\n*{len(figs) - limit} more figures in the JSON.*")
    return "\n".join(out)


def _band(region) -> str:
    """A region's fine-level band: the max over markers/points (GCI of the vector) or the pointwise band's max."""
    if isinstance(region, list):
        return _mm(max(p.get("gci_vector_mm", p.get("gci_fine_mm")) or 0.0 for p in region))
    return _mm(region["gci_mm"]["max"] if isinstance(region.get("gci_mm"), dict) else region.get("gci_mm"))


def convergence_table(result: dict) -> str:
    """A grid-convergence study: its levels, and per case the finest level's error band per region (mm)."""
    a = result["analysis"]
    levels = a.get("coarser_levels", []) + a["levels"]
    head = ", ".join(f"{lv['n_tets']:,} tets (x{lv['scale']:g})" for lv in levels)
    regions = (("markers", "markers"), ("interior", "interior points"), ("surface_near_tip", "surface < 8 mm from tip"),
               ("surface_rest", "rest of surface"), ("all_nodes", "every node"))
    out = [f"Levels: {head}; the band is the finest level's grid convergence index (Fs 1.25), max over the points, "
           f"in mm, from the three finest.", "",
           "| case | " + " | ".join(r for _, r in regions) + " | convergence (every node) |",
           "|---|" + "---|" * (len(regions) + 1)]
    for case, c in a["cases"].items():
        out.append(f"| {case} | " + " | ".join(_band(c[k]) for k, _ in regions)
                   + f" | {c['all_nodes'].get('mean_kind', '—')} |")
    return "\n".join(out)


def defaults_table(result: dict) -> str:
    """bench/service_defaults.py's result: each candidate configuration served (the defaults in bold), then where
    the defaults rank among them per model, core count and scenario."""
    out = ["| nodes | cores | scenario | configuration | req/s | p50 (ms) | p99 (ms) | mean batch |",
           "|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        config = f"**{r['config']}** (defaults)" if r["default"] else r["config"]
        batch = "—" if r.get("mean_batch") is None else f"{r['mean_batch']:.1f}"
        out.append(f"| {r['n_nodes']:,} | {r['cores']} | {r['scenario']} | {config} | {r['throughput_rps']:.0f} | "
                   f"{r['p50_ms']:.2f} | {r['p99_ms']:.2f} | {batch} |")
    out += ["", "| nodes | cores | scenario | defaults' rank, req/s | defaults' rank, p99 | req/s / the most | "
            "p99 / the lowest |", "|---|---|---|---|---|---|---|"]
    for s in result["defaults_summary"]:
        out.append(f"| {s['n_nodes']:,} | {s['cores']} | {s['scenario']} | {s['defaults_rps_rank']} of "
                   f"{s['candidates']} | {s['defaults_p99_rank']} of {s['candidates']} | "
                   f"{s['defaults_rps_vs_best']:.2f} | {s['defaults_p99_vs_best']:.2f} |")
    return "\n".join(out)


def result_block(name: str, folder: Path = DOCS_RESULTS) -> str:
    """The Markdown a docs page shows for docs/results/NAME.json: its figures, provenance and staleness."""
    result = load(name, folder)
    if result is None:
        return f"*No committed result `{name}` yet.*"
    if "report_md" in result:  # a study that wrote a Markdown report: shown under its own heading levels
        body = re.sub(r"^(#+) ", r"\1## ", result["report_md"].split("\n", 1)[1], flags=re.M)
        body = re.sub(r"\]\((\w+)\.(json|png)\)", r"](results/\1.\2)", body)
    elif "defaults_summary" in result:
        body = defaults_table(result)
    elif "analysis" in result and "levels" in result:
        body = convergence_table(result)
    elif isinstance(result.get("rows"), list) and result["rows"]:
        body = rows_table(result["rows"])
    elif isinstance(result.get("meshes"), list):
        body = rows_table(result["meshes"])
    elif "readme_rows" in result:
        body = speed_table(folder)
    else:
        body = figures_table(result)
    stale = stale_note(str(result.get("provenance", {}).get("commit", "")), code_paths(name))
    return "\n".join([stale, body, "", provenance_line(result), f"[{name}.json](results/{name}.json)", ""])


def material_check_table(manifest_path: Path = MANIFEST) -> str:
    """The default model's material check (manifest materials.accuracy): per region the first-order FE model and
    the served model against fresh FE at held-out material points, and the points where the FE found no
    equilibrium."""
    m = json.loads(Path(manifest_path).read_text())
    acc = (m.get("materials") or {}).get("accuracy")
    if not acc:
        return f"*`{m['name']}` has not been checked against fresh FE at held-out material points.*"
    rows = ["| region | first order (FE u0 + Σ S_i θ_i) vs fresh FE (mm) | served model vs fresh FE (mm) |",
            "|---|---|---|"]
    for key, label in REGIONS:
        if key in acc["regions"]:
            r = acc["regions"][key]
            rows.append(f"| {label} | {_mm(r['first_order_mm'])} | **{_mm(r['model_mm'])}** |")
    out = [f"Largest error over {acc['n_points']} material points: {acc['reference']}.", "", *rows]
    if acc.get("unsolved"):
        out += ["", "Where the FE found no equilibrium (not compared):", "",
                *[f"- {u}" for u in acc["unsolved"]]]
    return "\n".join(out + ["", f"*Generated from* `models/{m['name']}/manifest.json` (materials.accuracy)."])


def render_page(text: str, folder: Path = DOCS_RESULTS) -> str:
    """A page with each `{{ result NAME }}` replaced by that result's block, and `{{ accuracy }}`, `{{ speed }}`,
    `{{ material_check }}`, `{{ service_targets }}`."""
    text = re.sub(r"\{\{\s*result\s+\"?(\w+)\"?\s*\}\}", lambda m: result_block(m.group(1), folder), text)
    text = re.sub(r"\{\{\s*accuracy\s*\}\}", lambda m: accuracy_table(), text)
    text = re.sub(r"\{\{\s*material_check\s*\}\}", lambda m: material_check_table(), text)
    text = re.sub(r"\{\{\s*service_targets\s*\}\}", lambda m: service_targets_table(folder), text)
    return re.sub(r"\{\{\s*speed\s*\}\}", lambda m: speed_table(folder), text)
