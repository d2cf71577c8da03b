"""One command line for a package of studies or benchmarks: `python -m <package> NAME [flags]` or `--list`.

Each public module of the package (no leading underscore, not in the package's LIBRARY_MODULES) is a command named after
it (dashes for underscores). It has a module docstring, whose first line `--list` prints, and
`main(argv) -> int | None`, which parses its own flags with argparse.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from types import ModuleType


def commands(package: ModuleType) -> dict[str, str]:
    """Command name -> module name of every public module in `package`."""
    library = set(getattr(package, "LIBRARY_MODULES", ()))
    return {m.name.replace("_", "-"): m.name for m in pkgutil.iter_modules(package.__path__)
            if not m.name.startswith("_") and not m.ispkg and m.name not in library}


def summary(package: ModuleType, module: str) -> str:
    """The first line of a command module's docstring (imports the module)."""
    doc = importlib.import_module(f"{package.__name__}.{module}").__doc__ or ""
    return doc.strip().splitlines()[0] if doc.strip() else ""


def dispatch(package: ModuleType, argv: list[str] | None = None) -> int:
    """Run `NAME [flags]` from `package`; `--list` (or no NAME) lists the commands; an unknown NAME exits 2."""
    argv = sys.argv[1:] if argv is None else argv
    prog = f"python -m {package.__name__}"
    table = commands(package)
    if not argv or argv[0] in ("--list", "-l", "--help", "-h"):
        print(f"usage: {prog} NAME [flags]   ({prog} NAME --help for a command's flags)\n")
        width = max(map(len, table), default=0)
        for name, module in sorted(table.items()):
            print(f"  {name:<{width}}  {summary(package, module)}")
        return 0
    name, rest = argv[0], argv[1:]
    if name.replace("_", "-") not in table:
        print(f"{prog}: unknown command {name!r}; `{prog} --list` shows them", file=sys.stderr)
        return 2
    module = importlib.import_module(f"{package.__name__}.{table[name.replace('_', '-')]}")
    sys.argv = [f"{prog} {name}", *rest]
    result = module.main(rest)
    return int(result or 0)
