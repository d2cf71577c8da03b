"""Command line: `python -m pipeline build --scene patient.toml --out models/NAME [--work runs/NAME]`;
bad input gets one line, exit 2."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m pipeline", description=__doc__)
    ap.add_argument("-v", "--verbose", action="store_true")
    sub = ap.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="scene (e.g. a segmentation's) -> mesh -> sweep -> off-grid cases "
                                     "-> model folder (resumable)")
    b.add_argument("--scene", required=True, type=Path)
    b.add_argument("--out", required=True, type=Path, help="model folder, e.g. models/patient_a")
    b.add_argument("--work", type=Path, help="sweep and cases folder (default runs/<name of --out>)")
    b.add_argument("--offgrid", type=int, default=8, help="held-out off-grid FE cases (default 8)")
    b.add_argument("--rank", type=int, default=32, help="PCA modes (default 32, capped by the snapshots)")
    b.add_argument("--width", type=int, default=30, help="hidden neurons (default 30: on a 4 deg sweep, 60 overfits "
                   "between the angles, docs/results/sweep_density_patient.json)")
    b.add_argument("--workers", type=int, default=2)
    b.add_argument("--fe-estimate", type=Path, help="label-map FE error estimates, `python -m studies "
                   "labelmap-truth`'s JSON (default: the package's copy of docs/results/labelmap_truth.json): the row "
                   "of the map's voxel size, mesher and sizes goes into the manifest")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    from fem_offline.fe.newton import ConvergenceError
    from fem_offline.scene import SceneError

    from .build import FE_ESTIMATE, BuildOptions, build

    try:
        for name in ("offgrid", "rank", "width", "workers"):
            if getattr(args, name) < 1:
                raise ValueError(f"--{name}: must be at least 1")
        if args.fe_estimate is not None and not args.fe_estimate.is_file():
            raise ValueError(f"--fe-estimate: no such file {args.fe_estimate}")
        build(args.scene, args.out, work=args.work,
              options=BuildOptions(offgrid_cases=args.offgrid, rank=args.rank, width=args.width, workers=args.workers,
                                   fe_estimate=args.fe_estimate or FE_ESTIMATE))
    except (SceneError, ValueError, ConvergenceError, RuntimeError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: finished steps are kept; run the same command again to resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
