"""`python -m service --model models/default --host 127.0.0.1 --port 8000`: serve a model folder.

`python -m service export --model M --displacement-mm D --angle-deg B --out case.vtu`: write a deformed mesh.
"""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["export"]:  # the only subcommand; every other argument list serves, as before
        from .export_cli import main as export_main

        return export_main(argv[1:])
    from pydantic import ValidationError

    from .igtl import IgtlError
    from .model import ModelError
    from .settings import Settings

    ap = argparse.ArgumentParser(prog="python -m service", description=__doc__)
    for name, field in Settings.model_fields.items():
        ap.add_argument(f"--{name.replace('_', '-')}", dest=name, help=f"{field.description or name} "
                        f"(env DEFORM_{name.upper()}, default {field.default})")
    args = {k: v for k, v in vars(ap.parse_args(argv)).items() if v is not None}
    try:
        settings = Settings(**args)
        from .app import create_app

        app = create_app(settings)
    except ValidationError as exc:
        for err in exc.errors():
            print(f"error: --{'.'.join(map(str, err['loc'])).replace('_', '-')}: {err['msg']}", file=sys.stderr)
        return 2
    except (ModelError, IgtlError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    import uvicorn

    uvicorn.run(app, host=settings.host, port=settings.port, log_level=settings.log_level)
    return 0


if __name__ == "__main__":
    sys.exit(main())
