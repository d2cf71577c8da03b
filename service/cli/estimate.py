"""`python -m service estimate|plan --model M --body request.json`: POST /estimate and POST /plan, offline.

The body is the route's JSON (a file, or - for standard input); `plan` also takes `--lesion-mm X Y Z` and
`--displacement-mm D` instead. The reply is the route's JSON on standard output. A body the route would refuse:
one line per field, as the 422 names it, exit 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pydantic import ValidationError


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line instead of argparse's usage block
        raise ValueError(message)


def _parser(command: str) -> argparse.ArgumentParser:
    ap = _Parser(prog=f"python -m service {command}", description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True, help="model folder (models/default)")
    ap.add_argument("--body", help=f"the POST /{command} body as JSON: a file, or - for standard input")
    if command == "plan":
        ap.add_argument("--lesion-mm", type=float, nargs=3, metavar=("X", "Y", "Z"), help="the lesion, reference mm")
        ap.add_argument("--displacement-mm", type=float, help="the push the clinician wants, mm (default: the best)")
    return ap


def _body(command: str, args) -> dict:
    if args.body is not None:
        return json.loads(sys.stdin.read() if args.body == "-" else Path(args.body).read_text())
    if command == "plan" and args.lesion_mm is not None:
        body = {"lesion_mm": args.lesion_mm}
        return body | ({"displacement_mm": args.displacement_mm} if args.displacement_mm is not None else {})
    raise ValueError("--body" + (" or --lesion-mm" if command == "plan" else "") + " is required")


def run(command: str, argv: list[str]) -> dict:
    """The route's reply to the body the flags give; ValidationError or RequestProblem as the route would refuse."""
    from ..estimate.routes import Closing, run_estimate, run_plan
    from ..estimate.schemas import estimate_request_model, plan_request_model
    from ..info import model_info
    from ..model import Predictor, read_model_folder
    from ..settings import Settings

    args = _parser(command).parse_args(argv)
    body = _body(command, args)
    folder = read_model_folder(args.model)
    settings = Settings(model=args.model)
    info = model_info(folder, settings)
    closing = Closing.of(Predictor(folder))
    if command == "plan":
        return run_plan(closing, plan_request_model(info).model_validate(body))
    model = estimate_request_model(info, settings.max_points, len(closing.markers))
    return run_estimate(closing, model.model_validate(body))[0]


def main(command: str, argv: list[str] | None = None) -> int:
    from ..http import RequestProblem

    try:
        print(json.dumps(run(command, sys.argv[2:] if argv is None else argv), indent=1))
    except ValidationError as exc:
        for err in exc.errors(include_input=False):
            field = ".".join(map(str, err["loc"])) or "body"
            print(f"error: {field}: {err['msg']}", file=sys.stderr)
        return 2
    except RequestProblem as exc:
        print(f"error: {exc.detail}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as exc:  # ModelError and malformed JSON are ValueErrors
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0
