"""What a design model's accuracy costs in FE time: the fit on the first N points of one design, against held-out FE.

    python -m studies design-points --design runs/patient_design --held-out runs/patient_held_out \\
        [--points 4 8 16 32 64] [--workers 2] [--publish]

A scrambled Sobol design's first 2^k points are a design of their own, so one design (`fem_offline design`) gives
every smaller one for free. For each N, `training fit-design --points N` fits a model (runs/design_points/nN/) and the
study records, per region, its largest error over every held-out snapshot and at the largest push alone: the
surrogate against its own FE on the same mesh (the FE's discretisation error is the hard-cases page's GCI).

The cost of a design is measured on disk, so it survives every stop and resume: the solved (not mirrored) snapshots'
write times, in order, give the wall time between consecutive writes; gaps longer than --idle-gap seconds (the run
was stopped) are left out. Core-seconds per snapshot = wall per snapshot x the workers that wrote them (--workers).
A design of N points is N x its paths x their pushes snapshots; on c cores it takes about that x core-seconds / c
(the paths are independent; the per-snapshot cost includes the S_i a design solves every few pushes).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

# one thread for the fits (their round-off, so where L-BFGS stops, then does not depend on the machine's load)
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from studies import results

REGIONS = ("markers", "prostate_surface", "all_nodes")
TARGETS_MM = {"markers": 0.03, "prostate_surface": 0.05}  # at the largest push, over the box (issue 48)


def snapshot_cost(folder: Path, *, workers: int, idle_gap_s: float) -> dict:
    """Wall and core seconds per solved snapshot of a design folder, from the snapshots' write times."""
    times = []
    for path in folder.glob("p*/snapshots/*.npz"):
        with np.load(path) as z:
            if "mirrored_from" in z.files:
                continue
        times.append(path.stat().st_mtime)
    times = np.sort(np.asarray(times))
    gaps = np.diff(times)
    kept = gaps[gaps <= idle_gap_s]
    if len(kept) == 0:
        raise ValueError(f"{folder}: too few solved snapshots to time")
    wall = float(kept.mean())
    return {"solved_snapshots": len(times), "timed_gaps": len(kept), "left_out_gaps": int((gaps > idle_gap_s).sum()),
            "wall_s_per_snapshot": wall, "workers": workers, "core_s_per_snapshot": wall * workers}


def solved_per_point(folder: Path) -> int:
    """Solved (not mirrored) snapshots one point of the design needs: one path (beta >= 0; -beta is its mirror) of
    the largest push over the design's push step."""
    from contracts.design import read_design_file

    design = read_design_file(folder)
    sweep = design.scene.sweep
    return round(sweep.displacement_max_mm / (design.displacement_step_mm or sweep.displacement_step_mm))


def fit_one(design: Path, held_out: Path, n: int, out: Path, options) -> dict:
    from contracts.design import read_design
    from contracts.model import onnx_session
    from training.design_fit import fit_design, held_out_errors

    t0 = time.perf_counter()
    manifest = fit_design(design, out, options, points=n, progress=False)
    seconds = time.perf_counter() - t0
    test = read_design(held_out)
    checked = held_out_errors(onnx_session((out / "model.onnx").read_bytes()), test, test.mesh.node_sets)
    return {"points": n, "snapshots": manifest.network.n_train, "fit_seconds": seconds,
            "train_seconds": manifest.timing.train_seconds, "iterations": manifest.network.iterations,
            "rank": manifest.pca.rank, "regions": {k: checked["regions"][k] for k in REGIONS},
            "held_out_points": checked["n_points"], "held_out_snapshots": checked["n_snapshots"],
            "held_out_unfinished": checked["unfinished"]}


def run(design: Path, held_out: Path, points: list[int], options, *, workers: int, idle_gap_s: float,
        out: Path) -> dict:
    from contracts.design import read_design_file

    n_design = len(read_design_file(design).points)
    finished = _finished_points(design)
    usable = [n for n in points if n <= finished]
    if not usable:
        raise ValueError(f"--points: the design has {finished} finished points (of {n_design}), fewer than any asked")
    cost = snapshot_cost(design, workers=workers, idle_gap_s=idle_gap_s)
    per_point = solved_per_point(design)
    rows = []
    for n in usable:
        row = fit_one(design, held_out, n, out / f"n{n}", options)
        row["fe_core_hours"] = n * per_point * cost["core_s_per_snapshot"] / 3600
        rows.append(row)
        print(f"{n} points: markers {row['regions']['markers']['largest_push_mm']:.4f} mm, prostate surface "
              f"{row['regions']['prostate_surface']['largest_push_mm']:.4f} mm at the largest push; FE "
              f"{row['fe_core_hours']:.1f} core-hours, fit {row['fit_seconds']:.0f} s", flush=True)
    held_cost = snapshot_cost(held_out, workers=workers, idle_gap_s=idle_gap_s)
    return {"design": str(design), "held_out": str(held_out), "design_points": n_design, "finished_points": finished,
            "skipped_points": [n for n in points if n > finished], "solved_snapshots_per_point": per_point,
            "cost": cost, "held_out_cost": held_cost, "fit": options.model_dump(mode="json"), "rows": rows,
            "targets_mm": TARGETS_MM}


def _finished_points(design: Path) -> int:
    """How many of the design's first points are finished, in order."""
    from contracts.design import read_design_file
    from contracts.sweep import read_manifest

    n = 0
    for p in read_design_file(design).points:
        manifest = design / p.folder / "manifest.json"
        if not manifest.is_file():
            break
        m = read_manifest(design / p.folder)
        if m.n_done < m.n_expected:
            break
        n += 1
    return n


def wall_hours(core_hours: float, cores: int, paths: int) -> float:
    """Wall hours on `cores` cores: whole paths per core (a path is one process's work)."""
    return core_hours / min(cores, max(paths, 1)) if paths else 0.0


def report(data: dict) -> str:
    cost, rows = data["cost"], data["rows"]
    lines = ["# Accuracy against the number of material points", "",
             f"The first N points of `{data['design']}` ({data['finished_points']} of {data['design_points']} "
             f"finished), each fit against `{data['held_out']}`: {rows[0]['held_out_points']} held-out material points "
             f"(the box's corners first) at beta +-10 deg, every push ({rows[0]['held_out_snapshots']} snapshots). "
             "Errors are the largest nodal error, the surrogate against its own FE on the same mesh."
             + (f" Held-out points whose path stopped short of the largest push (what they reached counts under "
                f"every push): {', '.join(rows[0]['held_out_unfinished'])}." if rows[0]["held_out_unfinished"] else ""),
             "",
             "| points | snapshots | markers, largest push | prostate surface, largest push | every node, largest "
             "push | markers, every push | FE build | fit |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        g = r["regions"]
        lines.append(f"| {r['points']} | {r['snapshots']:,} | {g['markers']['largest_push_mm']:.4f} mm | "
                     f"{g['prostate_surface']['largest_push_mm']:.4f} mm | {g['all_nodes']['largest_push_mm']:.4f} mm "
                     f"| {g['markers']['all_mm']:.4f} mm | {r['fe_core_hours']:.1f} core-h | "
                     f"{r['fit_seconds']:.0f} s |")
    lines += ["", f"Targets at the largest push: markers <= {TARGETS_MM['markers']} mm, prostate surface <= "
              f"{TARGETS_MM['prostate_surface']} mm.", "",
              f"FE cost, measured from {cost['timed_gaps']:,} write times of {cost['solved_snapshots']:,} solved "
              f"snapshots on {cost['workers']} workers: {cost['wall_s_per_snapshot']:.2f} s wall, "
              f"{cost['core_s_per_snapshot']:.1f} core-seconds per snapshot (the S_i included); "
              f"{data['solved_snapshots_per_point']} solved snapshots per point (beta >= 0; beta < 0 is mirrored). "
              f"The held-out set: {data['held_out_cost']['core_s_per_snapshot']:.1f} core-seconds per snapshot.", "",
              "Wall time to expect for the whole design on c cores (one path per core at a time):", "",
              "| points | 2 cores | 8 cores | 16 cores | 64 cores |", "|---|---|---|---|---|"]
    per = data["solved_snapshots_per_point"]
    for n in sorted({r["points"] for r in rows} | {data["design_points"]}):
        core_h = n * per * cost["core_s_per_snapshot"] / 3600
        lines.append(f"| {n} | " + " | ".join(f"{wall_hours(core_h, c, n):.1f} h" for c in (2, 8, 16, 64)) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from contracts.cli import number
    from contracts.model import FitOptions

    ap = argparse.ArgumentParser(prog="python -m studies design-points", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--design", type=Path, default=Path("runs/patient_design"))
    ap.add_argument("--held-out", type=Path, default=Path("runs/patient_held_out"))
    ap.add_argument("--points", type=number("--points", int, minimum=1), nargs="+", default=[4, 8, 16, 32, 64])
    ap.add_argument("--rank", type=number("--rank", int, minimum=1), default=16)
    ap.add_argument("--sensitivity-rank", type=number("--sensitivity-rank", int, minimum=0), default=32)
    ap.add_argument("--width", type=number("--width", int, minimum=1), default=60)
    ap.add_argument("--iterations", type=number("--iterations", int, minimum=1), default=1000)
    ap.add_argument("--workers", type=number("--workers", int, minimum=1), default=2,
                    help="the workers the design ran on (default 2): core-seconds = wall x workers")
    ap.add_argument("--idle-gap", type=number("--idle-gap", minimum=1), default=300.0,
                    help="seconds between two writes above which the run counts as stopped (default 300)")
    ap.add_argument("--out", type=Path, default=Path("runs/design_points"), help="where the fitted models go")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    for name in ("design", "held_out"):
        if not (getattr(args, name) / "design.json").is_file():
            ap.error(f"--{name.replace('_', '-')}: {getattr(args, name)} is not a `fem_offline design` folder")
    options = FitOptions(rank=args.rank, sensitivity_rank=args.sensitivity_rank, width=args.width, depth=1,
                         max_iterations=args.iterations, seed=0, test_cases=())
    try:
        data = run(args.design, args.held_out, sorted(set(args.points)), options, workers=args.workers,
                   idle_gap_s=args.idle_gap, out=args.out)
    except ValueError as exc:
        ap.error(str(exc))
    data["report_md"] = report(data)
    path = results.write("design_points", data, publish=args.publish)
    print(data["report_md"])
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
