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


def add_crosspoint_options(parser: argparse.ArgumentParser, smooth_default: float, prefix: str = "") -> None:
    """The Detector's crosspoint-stage options, as every CLI that runs it names them:
    --smooth-crosspoints PX, --no-smooth-crosspoints (`crosspoint_options` reads them back).
    prefix: put before each help text (e.g. "networks mode: ")."""
    parser.add_argument("--smooth-crosspoints", type=float, default=smooth_default, metavar="PX",
                        help=f"{prefix}move each marker's visible crosspoints within this many crop pixels of a "
                        "cubic field fitted to them onto it (DetectorConfig.smooth_crosspoints_px; default %(default)s)")
    parser.add_argument("--no-smooth-crosspoints", action="store_true",
                        help=f"{prefix}the crosspoint network's raw outputs, unsmoothed (the reference's)")


def crosspoint_options(args: argparse.Namespace) -> dict[str, float | None]:
    """{smooth_crosspoints_px} of `add_crosspoint_options`' parsed arguments."""
    return {"smooth_crosspoints_px": None if args.no_smooth_crosspoints else args.smooth_crosspoints}


def parse_neighbour_fit(text: str) -> tuple[float | None, int]:
    """'1.5/2' -> (1.5, 2), 'none/0' -> (None, 0): the width (marker sides, or none for equal weights)
    and degree of the Detector's neighbour placement (`networks.neighbours.place_from_neighbours`).
    Raises ValueError (argparse's type error) for anything else: the values are checked by the
    Detector's own rule (`networks.config.neighbour_fit_problem`)."""
    from networks.config import neighbour_fit_problem  # torch-free

    try:
        width, degree = text.strip().lower().split("/")
        sigma = None if width == "none" else float(width)
        order = int(degree)
    except ValueError:
        raise ValueError(f"{text!r} is not WIDTH/DEGREE (WIDTH a number or none, DEGREE an integer)") from None
    if problem := neighbour_fit_problem(sigma, order):
        raise ValueError(f"{text!r}: {problem}")
    return sigma, order


def _neighbour_fit_arg(text: str) -> tuple[float | None, int]:
    try:
        return parse_neighbour_fit(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_completion_options(parser: argparse.ArgumentParser, keep_default: float,
                           fit_default: tuple[float | None, int], prefix: str = "") -> None:
    """How the Detector completes a marker its cut test flags and places the markers it grows, as every
    CLI that runs it names it: --keep-own CELLS, --replace-own, --neighbour-fit WIDTH/DEGREE
    (`completion_options` reads them back)."""
    parser.add_argument("--keep-own", type=float, default=keep_default, metavar="CELLS",
                        help=f"{prefix}a marker counted as cut keeps each of its own points within this many cells "
                        "of its neighbours' estimate (DetectorConfig.keep_own_cells; default %(default)s)")
    parser.add_argument("--replace-own", action="store_true",
                        help=f"{prefix}replace all five points of a marker counted as cut by its neighbours' estimate")
    default = f"{'none' if fit_default[0] is None else f'{fit_default[0]:g}'}/{fit_default[1]}"
    parser.add_argument("--neighbour-fit", type=_neighbour_fit_arg, default=fit_default, metavar="WIDTH/DEGREE",
                        help=f"{prefix}how markers are placed from their neighbours' points (growth, cut markers): "
                        "Gaussian weights of WIDTH marker sides (none: equal) and a residual polynomial of DEGREE; "
                        f"none/0 is one homography over the neighbourhood (default {default})")


def completion_options(args: argparse.Namespace) -> dict[str, float | int | None]:
    """{keep_own_cells, neighbour_sigma_sides, neighbour_degree} of `add_completion_options`' parsed
    arguments."""
    sigma, degree = args.neighbour_fit
    return {"keep_own_cells": None if args.replace_own else args.keep_own,
            "neighbour_sigma_sides": sigma, "neighbour_degree": degree}


def localizer_scale_arg(text: str) -> float | None:
    """argparse type of `--localizer-scale`: a number, or "auto" (None: chosen per image,
    `networks.DetectorConfig.localizer_scale`, which checks the number's range)."""
    if text.strip().lower() == "auto":
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or 'auto', got {text!r}") from None


# ---- the shared vocabulary: the same flag for the same thing in every CLI ----------------------------
#   --out DIR          where a command writes (a folder; never an input)
#   --device DEV       where torch/Cycles/warp work runs: cpu, cuda, cuda:1 (a CLI may accept a list)
#   --workers N        worker processes (data loading, rendering, detection, Ray tasks)
#   --no-progress      no progress bars (logging stays)
#   --checkpoint PT    the one network a command reads
#   --localizer PT --recognizer PT --crosspoints PT   the Detector's three networks
def add_out(parser: argparse.ArgumentParser, help: str, required: bool = True, default: str | None = None) -> None:
    parser.add_argument("--out", required=required, default=default, metavar="DIR", help=help)


def add_device(parser: argparse.ArgumentParser, help: str = "cpu, cuda or cuda:N (default: a CUDA GPU when there is one)",
               default: str | None = None) -> None:
    parser.add_argument("--device", default=default, metavar="DEV", help=help)


def add_workers(parser: argparse.ArgumentParser, help: str = "worker processes", default: int | None = None) -> None:
    parser.add_argument("--workers", type=int, default=default, metavar="N", help=help)


def add_progress(parser: argparse.ArgumentParser) -> None:
    """--no-progress; `progress(args)` reads it back as the `progress` flag the project's functions take."""
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def progress(args: argparse.Namespace) -> bool:
    return not args.no_progress


NETWORKS = ("localizer", "recognizer", "crosspoints")


def add_networks(parser: argparse.ArgumentParser, help_prefix: str = "") -> None:
    """--localizer PT --recognizer PT --crosspoints PT: the Detector's three networks
    (`networks_of(args)` reads them back, all three or none)."""
    for name in NETWORKS:
        parser.add_argument(f"--{name}", metavar="PT", help=f"{help_prefix}the {name} checkpoint")


def networks_of(args: argparse.Namespace) -> tuple[str, ...]:
    """The three checkpoints of `add_networks` in the Detector's order, () when none is given; a
    ValueError names the missing ones when only some are."""
    given = [getattr(args, name) for name in NETWORKS]
    if not any(given):
        return ()
    if missing := [f"--{n}" for n, g in zip(NETWORKS, given) if not g]:
        raise ValueError(f"the Detector needs all three networks: {', '.join(missing)} missing")
    return tuple(given)
