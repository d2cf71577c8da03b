"""`python -m service export --model M --displacement-mm D --angle-deg B --out case.vtu`: a deformed mesh file, offline.

The format follows the suffix of --out: .vtu (the volume), .ply or .glb (tissue surfaces); see
service/predict/export.py. Bad flags, an out-of-envelope case or a bad model folder: one line, exit 2.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..predict.export import ExportFormat, export_bytes


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line instead of argparse's usage block
        raise ValueError(message)


def _parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="python -m service export", description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True, help="model folder (models/default)")
    ap.add_argument("--displacement-mm", type=float, required=True, help="guide displacement, mm")
    ap.add_argument("--angle-deg", type=float, required=True, help="guide angle beta, degrees")
    ap.add_argument("--out", type=Path, required=True, help="output file: .vtu, .ply or .glb")
    return ap


def _export(args) -> str:
    from ..model import Predictor, read_model_folder

    suffix = args.out.suffix.lower().lstrip(".")
    if suffix not in ExportFormat.__members__:
        raise ValueError(f"--out: use .vtu, .ply or .glb, got {args.out.suffix or 'no suffix'}")
    folder = read_model_folder(args.model)
    envelope = folder.manifest.envelope
    for flag, value, (lo, hi) in (("--displacement-mm", args.displacement_mm, envelope.displacement_mm),
                                  ("--angle-deg", args.angle_deg, envelope.angle_deg)):
        if not (math.isfinite(value) and lo <= value <= hi):
            raise ValueError(f"{flag}: {value} is outside the model's envelope {lo}..{hi}")
    u = Predictor(folder).displacement(args.displacement_mm, args.angle_deg)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_bytes(export_bytes(folder, u, suffix))
    return (f"{args.out}: {suffix} of {folder.manifest.name} at {args.displacement_mm:g} mm, {args.angle_deg:g} deg "
            f"({len(folder.nodes)} nodes, max displacement {float((u ** 2).sum(1).max() ** 0.5):.3f} mm)")


def main(argv: list[str] | None = None) -> int:
    try:
        print(_export(_parser().parse_args(argv)))
    except (ValueError, OSError) as exc:  # ModelError is a ValueError
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0
