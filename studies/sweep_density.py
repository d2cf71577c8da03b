"""What a coarser sweep costs the surrogate: fit on every k-th angle and l-th displacement of one sweep.

    python -m studies sweep-density --sweep runs/default_v6 --offgrid runs/default_v6/offgrid [--publish]
        [--grids 1:1 2:1 4:1 1:2 2:2 4:2] [--configs 64:160:1 32:60:1] [--name sweep_density_patient]

A patient build must finish in 30 min (issue #14), and the sweep is most of that time. Its cost is
paths (one per solved angle) x load steps per path, so a sweep with every 2nd angle and a 0.5 mm step
costs about a quarter of the paper's 21 x 40. This script measures the other side: it fits the
default configuration (rank, width as models/default) on the sub-grids of one finished sweep and
evaluates each fit, float32 ONNX, on cases none of the sub-grids trained on (--configs: each
rank:width:depth is fitted on every sub-grid, to see whether a coarse grid wants a smaller network):
  off-grid   the sweep's off-grid FE cases (`fem_offline cases`, from rest), inside its valid envelope;
  left out   every snapshot of the full sweep that the sub-grid does not contain (for the full grid: none).
Errors are the surrogate's against the FE of the same mesh (largest nodal error per region); the FE's
own discretisation error adds to them unchanged (Grid convergence, README).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("MKL_NUM_THREADS", "1")  # reproducible fits (studies/tradeoff.py says why)
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from contracts.cli import number  # noqa: E402
from contracts.model import FitOptions, onnx_session  # noqa: E402
from studies import results  # noqa: E402
from training.fit import fit_surrogate, region_errors, training_set  # noqa: E402
from training.snapshots import read_offgrid, read_sweep, sub_grid, valid_part  # noqa: E402

DEFAULT = {"rank": 64, "width": 160, "depth": 1}  # models/default
GRIDS = ((1, 1), (2, 1), (4, 1), (1, 2), (2, 2), (4, 2))  # (angle stride, displacement stride)


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies sweep-density", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sweep", type=Path, required=True)
    ap.add_argument("--offgrid", type=Path, required=True)
    ap.add_argument("--name", default="sweep_density",
                    help="the result's name (sweep_density_patient for a patient's sweep)")
    results.add_publish_flag(ap)
    ap.add_argument("--seeds", type=number("--seeds", int, minimum=1), default=2,
                    help="fits per grid (seeds 0..n-1); the worst is reported")
    ap.add_argument("--grids", nargs="+", default=[f"{a}:{s}" for a, s in GRIDS],
                    help="angle_stride:displacement_stride sub-grids of the sweep's grid")
    ap.add_argument("--configs", nargs="+", default=["{rank}:{width}:{depth}".format(**DEFAULT)],
                    help="rank:width:depth of the fits (default: models/default's)")
    args = ap.parse_args(argv)
    try:
        grids = [tuple(int(v) for v in g.split(":")) for g in args.grids]
        configs = [dict(zip(("rank", "width", "depth"), (int(v) for v in c.split(":")))) for c in args.configs]
    except ValueError:
        ap.error("--grids takes angle_stride:displacement_stride, --configs rank:width:depth (integers)")
    if any(len(g) != 2 or min(g) < 1 for g in grids) or any(len(c) != 3 or min(c.values()) < 1 for c in configs):
        ap.error("--grids takes angle_stride:displacement_stride, --configs rank:width:depth (integers >= 1)")

    sweep = read_sweep(args.sweep)
    data, envelope, _ = valid_part(sweep)
    og_in, og_ref = read_offgrid(args.offgrid, len(sweep.mesh.nodes))
    inside = np.array([envelope.contains(*x) for x in og_in], dtype=bool)
    og_in, og_ref = og_in[inside], og_ref[inside]
    if not len(og_in):
        raise SystemExit(f"--offgrid: none of the {len(inside)} cases in {args.offgrid} "
                         "lies inside the sweep's valid envelope")
    n_angles, n_disps = len(np.unique(data.inputs[:, 1])), len(np.unique(data.inputs[:, 0][data.inputs[:, 0] > 0]))
    print(f"{args.sweep}: {len(data)} snapshots ({n_disps} displacements x {n_angles} angles), {len(sweep.mesh.nodes)} "
          f"nodes; {len(og_in)} off-grid cases", flush=True)
    rows = []
    for (a, s), config in tqdm([(g, c) for g in grids for c in configs], desc="fits", unit="grid"):
        mask = sub_grid(data.inputs, a, s) & (data.inputs[:, 0] > 0)
        left = ~mask & (data.inputs[:, 0] > 0)
        _, train_in, train_rows = training_set(data.select(mask), ())  # nothing held out: the rest of the grid is
        worst = {"offgrid": {}, "left_out": {}}
        t = []
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            fitted = fit_surrogate(train_in, train_rows, FitOptions(rank=min(config["rank"], len(train_in) - 1),
                                                                    width=config["width"], depth=config["depth"],
                                                                    seed=seed))
            t.append(time.perf_counter() - t0)
            session = onnx_session(fitted.onnx_bytes())
            for name, (x, ref) in {"offgrid": (og_in, og_ref),
                                   "left_out": (data.inputs[left], data.displacement[left])}.items():
                if len(x):
                    err = region_errors(session, x, ref, sweep.mesh.node_sets)
                    worst[name] = {k: max(v, worst[name].get(k, 0.0)) for k, v in err.items()}
        n_paths = len(np.unique(train_in[:, 1]))
        row = {"angle_stride": a, "displacement_stride": s, "snapshots": int(mask.sum()), "angles": n_paths,
               "angle_step_deg": float(np.diff(np.unique(train_in[:, 1])).max()),
               "displacement_step_mm": float(np.diff(np.unique(np.r_[0.0, train_in[:, 0]])).max()),
               "n_left_out": int(left.sum()), "rank": min(config["rank"], len(train_in) - 1),
               "width": config["width"], "depth": config["depth"],
               "fit_s": float(np.median(t)), **worst}
        rows.append(row)
        og, lo = worst["offgrid"], worst["left_out"]
        print(f"  {row['angle_step_deg']:g} deg x {row['displacement_step_mm']:g} mm ({row['snapshots']} snapshots, "
              f"rank {row['rank']} x {config['depth']}x{config['width']}, "
              f"{n_paths} angles): off-grid markers {og['markers']:.4f} / surface {og['prostate_surface']:.4f} / all "
              f"{og['all_nodes']:.4f} mm" + (f"; left-out grid markers {lo['markers']:.4f} / surface "
                                             f"{lo['prostate_surface']:.4f} / all {lo['all_nodes']:.4f} mm" if lo
                                             else ""),
              flush=True)
    path = results.write(args.name, {"sweep": str(args.sweep), "offgrid": str(args.offgrid), "n_offgrid": len(og_in),
                                     "seeds": args.seeds, "configs": configs, "rows": rows}, publish=args.publish)
    print(f"wrote {path}")
    return 0
