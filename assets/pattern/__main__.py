"""Write a printable two-level pattern, its marker table and a preview.

    python -m assets.pattern --out out/pattern                       # default 32 x 32 markers, 300 DPI
    python -m assets.pattern --out out/small --rows 4 --cols 6 --dpi 150
    python -m assets.pattern --out out/shirt --panels panels.json     # print only inside panel outlines

The folder gets pattern.png, preview.png, marker_table.npz/.json (and reference_textures.npz) and
spec.json, all replaced together: a run that fails (a bad argument, a full disk) leaves the folder as
it was.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

from assets.cli import run_cli
from assets.fileio import check_limit, load_json, save_npz, staged_outputs
from assets.pattern.codebook import MAX_NUM_IDS, generate_codebook
from assets.pattern.crops import CROSSPOINT_CROP, RECOGNIZER_CROP, reference_textures
from assets.pattern.raster import MAX_PIXELS, panel_bounds, region_shape, render_region, validate_polygons, write_png
from assets.pattern.spec import PatternSpec
from assets.pattern.table import MarkerTable

log = logging.getLogger("assets.pattern")


def build_parser() -> argparse.ArgumentParser:
    defaults = PatternSpec()
    parser = argparse.ArgumentParser(
        prog="python -m assets.pattern",
        description=(
            "Generate the two-level marker pattern: a printable PNG at exact physical scale (DPI in "
            "the file), the marker table (every marker's ID, localization points and crosspoints in "
            "pattern coordinates) as NPZ plus a JSON summary, and a small preview."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    parser.add_argument("--spec", type=Path, help="PatternSpec JSON; the flags below override its fields")
    parser.add_argument("--pitch-mm", type=float, help=f"crosspoint pitch [default {defaults.pitch_mm}]")
    parser.add_argument("--rows", type=int, help=f"marker rows [default {defaults.rows}]")
    parser.add_argument("--cols", type=int, help=f"marker columns [default {defaults.cols}]")
    parser.add_argument(
        "--fabric-m",
        type=float,
        nargs=2,
        metavar=("WIDTH", "HEIGHT"),
        help="instead of --rows/--cols: the smallest marker grid covering a WIDTH x HEIGHT metre fabric",
    )
    parser.add_argument("--seed", type=int, help=f"codebook seed [default {defaults.seed}]")
    parser.add_argument("--dpi", type=float, default=300.0, help="resolution of the printable PNG")
    parser.add_argument(
        "--panels",
        type=Path,
        help='JSON {"polygons": [[[x, y], ...], ...]} of panel outlines in pattern metres: print only '
        "their inside, with a cut line",
    )
    parser.add_argument("--margin-mm", type=float, default=10.0, help="border around the panels' bounding box")
    parser.add_argument("--preview-px", type=int, default=2048, help="longest side of preview.png")
    parser.add_argument("--max-pixels", type=float, default=MAX_PIXELS,
                        help="refuse a pattern.png of more pixels than this (its memory: 3 bytes a pixel, twice)")
    parser.add_argument("--max-ids", type=int, default=MAX_NUM_IDS,
                        help="refuse a spec of more codebook IDs (num_ids) than this (the search costs num_ids squared)")
    parser.add_argument(
        "--reference-textures",
        action="store_true",
        help="also write reference_textures.npz: every marker's 96 px recognizer and 112 px crosspoint crop",
    )
    return parser


def spec_from_args(args: argparse.Namespace) -> PatternSpec:
    """The spec of --spec and the flags that override it; a ValueError names the file or flag."""
    spec = PatternSpec.load(args.spec) if args.spec else PatternSpec()
    overrides = {
        "pitch_mm": args.pitch_mm,
        "rows": args.rows,
        "cols": args.cols,
        "seed": args.seed,
    }
    overrides = {k: v for k, v in overrides.items() if v is not None}
    flags = "/".join(f"--{k.replace('_', '-')}" for k in overrides) or "--spec"
    try:
        if args.fabric_m is not None:
            if args.rows is not None or args.cols is not None:
                raise ValueError("give either --fabric-m or --rows/--cols, not both")
            spec = PatternSpec.covering(*args.fabric_m, **{**spec.to_dict(), **overrides})
        elif overrides:
            spec = dataclasses.replace(spec, **overrides)
    except ValueError as exc:
        raise ValueError(f"{flags}{'/--fabric-m' if args.fabric_m is not None else ''}: {exc}") from None
    check_limit(spec.num_ids, args.max_ids, "num_ids (codebook size; its search costs num_ids squared)",
                str(args.spec or "PatternSpec"), "--max-ids")
    return spec


def load_panels(path: Path) -> list[np.ndarray]:
    """The polygons of a --panels file, each (K, 2) float64 from JSON numbers (not strings)."""
    data = load_json(path)
    polygons = data.get("polygons") if isinstance(data, dict) else data
    if not isinstance(polygons, list) or not polygons:
        raise ValueError(f'{path}: expected {{"polygons": [[[x, y], ...], ...]}} with at least one polygon')
    arrays = []
    for i, polygon in enumerate(polygons):
        try:
            array = np.asarray(polygon)
        except ValueError:  # ragged
            array = np.zeros(0)
        if array.dtype.kind not in "iuf" or array.ndim != 2 or array.shape[1:] != (2,):
            raise ValueError(f"{path}: polygons[{i}] must be a list of [x, y] numbers, got {str(polygon)[:80]}")
        arrays.append(array.astype(np.float64))
    return arrays


def check_arguments(args: argparse.Namespace) -> None:
    """Refuse bad numbers among the arguments before anything is computed or written."""
    if not (math.isfinite(args.dpi) and args.dpi > 0):
        raise ValueError(f"--dpi must be a positive number, got {args.dpi}")
    if args.preview_px < 16:
        raise ValueError(f"--preview-px must be >= 16, got {args.preview_px}")
    if not (math.isfinite(args.margin_mm) and args.margin_mm >= 0):
        raise ValueError(f"--margin-mm must be a number >= 0, got {args.margin_mm}")


def run(args: argparse.Namespace) -> dict[str, Path]:
    """Do the work of the CLI; returns the files written.  Every argument is checked first, and the
    files are replaced together (`staged_outputs`)."""
    check_arguments(args)
    spec = spec_from_args(args)
    polygons = validate_polygons(spec, load_panels(args.panels), str(args.panels)) if args.panels else []
    bounds = panel_bounds(polygons, args.margin_mm * 1e-3) if polygons else spec.fabric_bounds
    height, width = region_shape(bounds, args.dpi)
    check_limit(width * height, args.max_pixels, f"pattern.png ({width:,} x {height:,} px at {args.dpi:g} DPI) in "
                "pixels", "--dpi", "--max-pixels")
    with staged_outputs(args.out) as out:
        files = write_outputs(args, spec, polygons, bounds, out)
    return {name: args.out / path.name for name, path in files.items()}


def write_outputs(args: argparse.Namespace, spec: PatternSpec, polygons: list[np.ndarray],
                  bounds: tuple[float, float, float, float], out: Path) -> dict[str, Path]:
    """Render and write every file of the folder into `out`; returns them by role."""
    t0 = time.perf_counter()
    table = MarkerTable.build(spec, generate_codebook(spec, args.max_ids))
    log.info("codebook and marker table: %d markers in %.1f s", table.num_markers, time.perf_counter() - t0)
    files = {
        "spec": out / "spec.json",
        "pattern": out / "pattern.png",
        "table": out / "marker_table.npz",
        "summary": out / "marker_table.json",
        "preview": out / "preview.png",
    }
    image = render_region(table, bounds, args.dpi, polygons, progress=True)
    log.info("pattern %d x %d px at %g DPI", image.shape[1], image.shape[0], args.dpi)
    write_png(files["pattern"], image, args.dpi)
    del image
    side = max(bounds[2] - bounds[0], bounds[3] - bounds[1])
    preview_dpi = min(args.dpi, math.floor(args.preview_px / (side / 0.0254)))
    write_png(files["preview"], render_region(table, bounds, max(preview_dpi, 1e-3), polygons), preview_dpi)
    table.save(files["table"], files["summary"])
    if args.reference_textures:
        files["references"] = out / "reference_textures.npz"
        save_npz(
            files["references"],
            {
                "marker_ids": table.marker_ids,
                "recognizer": reference_textures(spec, table.codes, RECOGNIZER_CROP),
                "crosspoint": reference_textures(spec, table.codes, CROSSPOINT_CROP),
            },
        )
    spec.save(files["spec"])
    log.info("wrote %s in %.1f s", ", ".join(p.name for p in files.values()), time.perf_counter() - t0)
    return files


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_cli(lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
