"""`python -m service --model models/default --host 127.0.0.1 --port 8000`: serve a model folder.

`python -m service export --model M --displacement-mm D --angle-deg B --out case.vtu`: write a deformed mesh.

`python -m service estimate|plan --model M --body request.json`: POST /estimate or /plan offline, the reply on stdout.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["export"]:  # a subcommand; every other argument list serves, as before
        from .cli.export import main as export_main

        return export_main(argv[1:])
    if argv[:1] in (["estimate"], ["plan"]):  # POST /estimate and /plan, offline (service/cli/estimate.py)
        from .cli.estimate import main as estimate_main

        return estimate_main(argv[0], argv[1:])
    from pydantic import ValidationError

    from .igtl import IgtlError, devices_help
    from .model import ModelError
    from .settings import Settings

    ap = argparse.ArgumentParser(prog="python -m service", description=__doc__, epilog=devices_help(),
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    for name, field in Settings.model_fields.items():
        shown = ("from the usable cores" if field.default_factory is not None else
                 "none" if field.repr is False or field.default in (None, []) else field.default)
        ap.add_argument(f"--{name.replace('_', '-')}", dest=name, help=f"{field.description or name} "
                        f"(env DEFORM_{name.upper()}, default {shown})")
    args = {k: v for k, v in vars(ap.parse_args(argv)).items() if v is not None}
    try:
        settings = Settings(**args)
        from .app import create_app

        app = create_app(settings)  # also checks the model folder before any worker starts
    except ValidationError as exc:
        for err in exc.errors():
            where = ".".join(map(str, err["loc"])).replace("_", "-")
            print(f"error: {'--' + where + ': ' if where else ''}{err['msg']}", file=sys.stderr)
        return 2
    except (ModelError, IgtlError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    import uvicorn

    from .middleware.metrics import MULTIPROCESS_DIR

    metrics_dir = None
    if settings.workers > 1:
        # Each worker process builds its own app from the environment: hand it the flags as DEFORM_* variables,
        # and a folder where the workers' metrics meet.
        metrics_dir = tempfile.mkdtemp(prefix="deform-metrics-")
        os.environ.update({f"DEFORM_{name.upper()}": value for name, value in args.items()})
        os.environ[MULTIPROCESS_DIR] = metrics_dir
        app = "service.app:create_app"
    try:
        uvicorn.run(app, factory=settings.workers > 1, workers=settings.workers, host=settings.host,
                    port=settings.port, log_level=settings.log_level, access_log=settings.access_log == "text",
                    ssl_certfile=settings.ssl_certfile, ssl_keyfile=settings.ssl_keyfile)
    finally:
        if metrics_dir:
            shutil.rmtree(metrics_dir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
