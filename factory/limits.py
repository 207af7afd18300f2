"""Bounds on the sizes a factory command line asks for, checked before anything is allocated.

A mistyped size (``--resolution 100000x100000``, ``--frames 1e9``) would otherwise allocate until the
machine runs out of memory or render for weeks.  The defaults are far above any dataset the project
makes; ``--limit NAME=VALUE`` (repeatable) raises one for a run that really needs more.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields, replace

from assets.fileio import check_limit


@dataclass(frozen=True)
class Limits:
    #: pixels of one rendered image (width x height): 8K square
    pixels: int = 8192 * 8192
    #: render samples per pixel
    samples: int = 16384
    #: simulation frames at 120 Hz (5 minutes)
    frames: int = 36_000
    #: images per simulation frame of a dataset
    variations: int = 1000
    #: cameras of a capture
    cameras: int = 256

    def check(self, name: str, value: float, what: str, source: str) -> None:
        """Refuse `value` (of `source`, an argument) above limit `name`, naming the option that raises it."""
        check_limit(value, getattr(self, name), what, source, f"--limit {name}=N")


def add_limit_option(parser: argparse.ArgumentParser) -> None:
    names = ", ".join(f"{f.name} ({f.default:,})" for f in fields(Limits))
    parser.add_argument("--limit", action="append", default=[], metavar="NAME=VALUE",
                        help=f"raise a bound on what the command may ask for (repeatable): {names}")


def limits_from_args(args: argparse.Namespace) -> Limits:
    """The `Limits` of `add_limit_option`'s parsed ``--limit NAME=VALUE`` items."""
    known = {f.name for f in fields(Limits)}
    changes = {}
    for item in args.limit:
        name, _, value = item.partition("=")
        if name not in known:
            raise ValueError(f"--limit {item!r}: expected NAME=VALUE with NAME one of {', '.join(sorted(known))}")
        try:
            changes[name] = int(float(value))
        except (ValueError, OverflowError):
            raise ValueError(f"--limit {item!r}: {value!r} is not a finite number") from None
    return replace(Limits(), **changes)
