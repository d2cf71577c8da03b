"""The command-line conventions every stage shares: a bad flag value is one line naming the flag."""

from __future__ import annotations

import argparse
import math


def number(flag: str, cast: type = float, *, minimum: float | None = None):
    """An argparse `type` that parses `cast` (float or int), refuses NaN/inf and values below `minimum`."""
    kind = "an integer" if cast is int else "a number"

    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be {kind}, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{flag} must be finite, got {text!r}")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"{flag} must be at least {minimum}, got {value}")
        return value

    return parse
