"""A benchmark's printed lines, kept for its result (results.write) as they are printed."""

from __future__ import annotations


class Report:
    """Print a line as it is measured and keep it: `say = Report(); say("p50 1.2 ms"); say.lines`."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def __call__(self, text: str = "", **print_kwargs) -> None:
        print(text, flush=True, **{k: v for k, v in print_kwargs.items() if k != "flush"})
        self.lines.append(str(text))
