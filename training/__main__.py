"""Command line: `python -m training fit --snapshots DIR --out models/NAME`, `python -m training restamp --model
models/NAME --fe-error JSON`, `python -m training material-check --model models/NAME --cases DIR`, `python -m training
regraph --model models/NAME`; bad input gets one line, exit code 2."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

# One thread for numpy and torch unless the caller sets otherwise, before either loads (as `python -m studies
# tradeoff`): the fit's round-off, and so where L-BFGS stops, then does not depend on the cores or the machine's load,
# and a rerun gives the same model.onnx byte for byte. With more threads on a busy machine the fit can stop far from
# where one thread takes it (CHANGELOG, issue 50).
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from contracts.cli import number


def _case(text: str) -> tuple[float, float]:
    try:
        d, a = (float(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--test-case: expected DISPLACEMENT_MM/ANGLE_DEG like 7.75/-5, "
                                         f"got {text!r}") from None
    return d, a


def _network_flags(p: argparse.ArgumentParser, *, sensitivity_minimum: int) -> None:
    """The PCA and network flags `fit` and `fit-design` share."""
    p.add_argument("--rank", type=number("--rank", int, minimum=1), default=16,
                   help="u / d's PCA modes (default 16, the paper's)")
    p.add_argument("--sensitivity-rank", type=number("--sensitivity-rank", int, minimum=sensitivity_minimum),
                   default=32, help="extra modes for what u's leave of the sensitivities S_i / d (default 32)")
    p.add_argument("--width", type=number("--width", int, minimum=1), default=60,
                   help="hidden units per layer (default 60)")
    p.add_argument("--iterations", type=number("--iterations", int, minimum=1), default=1000,
                   help="L-BFGS iterations (default 1000)")
    p.add_argument("--seed", type=number("--seed", int), default=0)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m training", description=__doc__)
    ap.add_argument("-v", "--verbose", action="store_true")
    sub = ap.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fit", help="PCA + MLP on a sweep, exported to a model folder")
    f.add_argument("--snapshots", required=True, type=Path, help="a `fem_offline sweep` output folder")
    f.add_argument("--out", required=True, type=Path, help="model folder to write, e.g. models/default")
    f.add_argument("--offgrid", type=Path, help="folder of `fem_offline cases` cases to evaluate on")
    f.add_argument("--fe-error", type=Path, help="a grid-convergence study of this mesh "
                   "(docs/results/convergence_taylor_hood.json): the FE discretisation error, added to the surrogate's "
                   "for the end-to-end bound")
    _network_flags(f, sensitivity_minimum=1)
    f.add_argument("--depth", type=number("--depth", int, minimum=1), default=1, help="hidden layers (default 1)")
    f.add_argument("--test-case", type=_case, action="append",
                   help="held-out snapshot D/A (repeatable; default: the paper's five)")
    r = sub.add_parser("restamp",
                       help="stamp a model folder's accuracy again with another FE estimate, without refitting")
    r.add_argument("--model", required=True, type=Path, help="the model folder, e.g. models/default")
    r.add_argument("--fe-error", required=True, type=Path,
                   help="`python -m studies model-vs-converged`'s JSON for this model "
                        "(docs/results/fe_error_default.json)")
    k = sub.add_parser("material-check", help="stamp a material model with its first-order material model's error "
                       "against fresh FE (`fem_offline material-cases`), without refitting")
    k.add_argument("--model", required=True, type=Path, help="the model folder, e.g. models/default")
    k.add_argument("--cases", required=True, type=Path, help="a `fem_offline material-cases` output folder on its mesh")
    e = sub.add_parser("fit-design", help="PCA + a network on (d, beta, theta) fitted to values and theta-derivatives "
                       "of a `fem_offline design` folder: a model right over the stiffness box, not first order")
    e.add_argument("--design", required=True, type=Path, help="a `fem_offline design` output folder")
    e.add_argument("--out", required=True, type=Path, help="model folder to write, e.g. models/default")
    e.add_argument("--held-out", type=Path,
                   help="a `fem_offline design --held-out` folder on the same mesh to check against")
    _network_flags(e, sensitivity_minimum=0)
    e.add_argument("--points", type=number("--points", int, minimum=1),
                   help="fit on the design's first N points only (default all; a Sobol design's first 2^k are a "
                        "design of their own): what fewer FE paths cost in accuracy")
    g = sub.add_parser("regraph", help="rebuild a material model's ONNX graph from its own weights with today's graph "
                       "builder, without refitting (refused unless both graphs answer the same)")
    g.add_argument("--model", required=True, type=Path, help="the model folder, e.g. models/default")
    return ap


def _stamped(stamp, *args):
    """A stamp's new manifest, or None after printing the one-line error (the CLI then exits 2)."""
    try:
        return stamp(*args)
    except (ValueError, FileNotFoundError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None


def _material_check(args) -> int:
    from .materials import stamp

    manifest = _stamped(stamp, args.model, args.cases)
    if manifest is None:
        return 2
    acc = manifest.materials.accuracy
    for name, r in acc.regions.items():
        print(f"{args.model}: {name}: first order vs fresh FE {r.first_order_mm:.4f} mm, model {r.model_mm:.4f} mm "
              f"({acc.n_points} material points)")
    for point in acc.unsolved:
        print(f"{args.model}: not compared, the FE found no equilibrium at {point}")
    return 0


def _restamp(args) -> int:
    from .fit import restamp, summary_line

    manifest = _stamped(restamp, args.model, args.fe_error)
    if manifest is None:
        return 2
    print(f"{args.model}: {summary_line(manifest)}")
    return 0


def _regraph(args) -> int:
    from .materials import REGRAPH_TOLERANCE_MM, regraph

    diffs = _stamped(regraph, args.model)
    if diffs is None:
        return 2
    print(f"{args.model}: model.onnx rebuilt; against the old graph, over the sweep's guides at the nominal materials "
          f"and every corner of the ranges: displacement {diffs[0]:.2g} mm, std {diffs[1]:.2g} mm "
          f"(at most {REGRAPH_TOLERANCE_MM:g})")
    return 0


def _fit_design(args) -> int:
    from contracts.model import FitOptions

    from .design_fit import fit_design

    options = FitOptions(rank=args.rank, sensitivity_rank=args.sensitivity_rank, width=args.width, depth=1,
                         max_iterations=args.iterations, seed=args.seed, test_cases=())
    try:
        manifest = fit_design(args.design, args.out, options, held_out=args.held_out, points=args.points)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    acc = manifest.accuracy
    worst = ", ".join(f"{k} {v.surrogate_mm:.4f} mm" for k, v in acc.regions.items()) or acc.reference
    print(f"{args.out}: {manifest.network.n_train} snapshots, rank {manifest.pca.rank}, "
          f"{manifest.timing.train_seconds:.1f} s; held-out: {worst}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if args.command == "restamp":
        return _restamp(args)
    if args.command == "material-check":
        return _material_check(args)
    if args.command == "regraph":
        return _regraph(args)
    if args.command == "fit-design":
        return _fit_design(args)
    from .fit import PAPER_TEST_CASES, FitOptions, fit, summary_line

    options = FitOptions(rank=args.rank, sensitivity_rank=args.sensitivity_rank, width=args.width, depth=args.depth,
                         max_iterations=args.iterations,
                         seed=args.seed, test_cases=tuple(args.test_case or PAPER_TEST_CASES))
    try:
        manifest = fit(args.snapshots, args.out, options, offgrid=args.offgrid, fe_error=args.fe_error)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"interrupted: {args.out} was left as it was", file=sys.stderr)
        return 130
    print(f"{args.out}: {summary_line(manifest)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
