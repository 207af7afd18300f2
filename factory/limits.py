"""Bounds on the sizes a factory command line asks for, checked before anything is allocated.

A mistyped size (``--resolution 100000x100000``, ``--frames 1e9``) would otherwise allocate until the
machine runs out of memory or render for weeks.  The defaults are far above any dataset the project
makes; ``--max-NAME N`` (``--max-pixels``, ``--max-frames``, ...) raises one for a run that really
needs more, as the assets CLIs' ``--max-*`` options do.
"""

from __future__ import annotations

import argparse
import math
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
        check_limit(value, getattr(self, name), what, source, f"--max-{name}")


def add_limit_options(parser: argparse.ArgumentParser, names: tuple[str, ...] | None = None) -> None:
    """``--max-NAME N`` for the `Limits` named (default: all)."""
    for f in fields(Limits):
        if names is None or f.name in names:
            parser.add_argument(f"--max-{f.name}", type=float, default=f.default, metavar="N",
                                help=f"refuse a run asking for more {f.name} than this (default %(default)d)")


def limits_from_args(args: argparse.Namespace) -> Limits:
    """The `Limits` of `add_limit_options`' parsed arguments (defaults for those not given)."""
    changes = {}
    for f in fields(Limits):
        value = getattr(args, f"max_{f.name}", None)
        if value is None:
            continue
        if not (math.isfinite(value) and value >= 1):
            raise ValueError(f"--max-{f.name} must be a finite number >= 1, got {value}")
        changes[f.name] = int(value)
    return replace(Limits(), **changes)
