"""What every command-line tool of the project shares: logging set-up and how bad input is reported."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Callable


def run_cli(action: Callable[[], object], failures: tuple[type[Exception], ...] = ()) -> int:
    """Run a CLI's work.  Bad input (ValueError, including PatternError, or a missing/unreadable file)
    is printed as ``error: ...`` on stderr with exit status 2, never as a traceback; the work's own
    `failures` (a simulation that blew up, a garment that cannot be dressed) likewise with status 1."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        action()
    except failures as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


def localizer_scale_arg(text: str) -> float | None:
    """argparse type of `--localizer-scale`: a number, or "auto" (None: chosen per image,
    `networks.DetectorConfig.localizer_scale`, which checks the number's range)."""
    if text.strip().lower() == "auto":
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or 'auto', got {text!r}") from None
