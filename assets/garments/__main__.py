"""Build garment templates from sewing patterns.

    python -m assets.garments build shirt --levels 12,4,2,1 --out out/shirt
    python -m assets.garments build my_pattern.json --out out/mine          # our format or GarmentCode
    python -m assets.garments list
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
import time
from pathlib import Path


from assets.cli import run_cli
from assets.fileio import check_limit, save_json, staged_outputs
from assets.garments.defaults import DEFAULT_GARMENTS, default_pattern
from assets.garments.export import FORMATS, export_level, flat_positions, placed_positions
from assets.garments.loading import load_pattern
from assets.garments.mesh import triangle_quality
from assets.garments.sewing import MAX_PANEL_M
from assets.garments.template import LEVELS_MM, Template
from assets.pattern.raster import MAX_PIXELS, write_png
from assets.pattern.spec import PatternSpec

log = logging.getLogger("assets.garments")


def level_summary(template: Template, mm: int) -> dict[str, object]:
    level = template.level(mm)
    area, min_angle = triangle_quality(level.pattern_xy, level.faces)
    grid = (level.flags[level.faces] & 1).all(axis=1)
    return {
        "spacing_mm": mm,
        "vertices": level.num_vertices,
        "sewn_vertices": level.num_sewn_vertices,
        "triangles": int(len(level.faces)),
        "seam_pairs": int(len(level.seam_pairs)),
        "crosspoint_vertices": int((level.crosspoint >= 0).sum()),
        "min_angle_band_deg": float(min_angle[~grid].min()) if (~grid).any() else None,
        "area_m2": float(area.sum()),
    }


def checked_arguments(args: argparse.Namespace) -> tuple[tuple[int, ...], list[str], PatternSpec]:
    """The levels, formats and pattern spec of `build`'s arguments, every one checked before anything
    is read or written; a ValueError names the argument."""
    try:
        levels = tuple(int(v) for v in args.levels.split(","))
    except ValueError:
        levels = ()
    if not levels or any(v <= 0 for v in levels):
        raise ValueError(f"--levels must be positive whole millimetres separated by commas, got {args.levels!r}")
    formats = [f for f in args.formats.split(",") if f]
    unknown = sorted(set(formats) - set(FORMATS))
    if unknown or not formats:
        raise ValueError(f"--formats: unknown {', '.join(unknown) or 'none given'} (use {', '.join(FORMATS)})")
    if not (math.isfinite(args.dpi) and args.dpi > 0):
        raise ValueError(f"--dpi must be a positive number, got {args.dpi}")
    try:
        spec = dataclasses.replace(PatternSpec(), pitch_mm=args.pitch_mm, seed=args.seed)
    except ValueError as exc:
        raise ValueError(f"--pitch-mm/--seed: {exc}") from None
    return levels, formats, spec


def build(args: argparse.Namespace) -> dict[str, object]:
    """Build the template and write every output into `args.out` together (`staged_outputs`): a run
    that fails leaves the folder as it was."""
    levels, formats, spec = checked_arguments(args)
    pattern = load_pattern(args.garment, args.max_panel_m)
    t0 = time.perf_counter()
    template = Template.build(pattern, spec, args.dpi)
    width, height = template.layout.size_px
    check_limit(width * height, args.max_pixels, f"the pattern sheet ({width} x {height} px at {args.dpi:g} DPI) "
                "in pixels", "--dpi", "--max-pixels")
    summaries = []
    with staged_outputs(args.out) as out:
        texture = out / "pattern_texture.png"
        sheet = template.layout.render(pattern, progress=True)
        write_png(texture, sheet, args.dpi)
        del sheet
        for mm in levels:
            t = time.perf_counter()
            template.level(mm)
            summary = level_summary(template, mm)
            summary["build_s"] = time.perf_counter() - t
            summaries.append(summary)
            positions = flat_positions(template, mm) if args.flat else placed_positions(template, mm)
            for fmt in formats:
                export_level(template, mm, out / f"{pattern.name}_{mm}mm.{fmt}", positions, texture)
        template.save(out / "template.npz", levels)
        pattern.save(out / "pattern.json")
        result = _summary(template, args.dpi, summaries, time.perf_counter() - t0)
        save_json(out / "summary.json", result)
    print(f"{pattern.name}: {len(pattern.panels)} panels, {result['markers']} markers, "
          f"sheet {width} x {height} px at {args.dpi:g} DPI")
    print("| level | vertices | triangles | seam pairs | crosspoint vertices | min band angle | build s |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for s in summaries:
        print(f"| {s['spacing_mm']} mm | {s['vertices']} | {s['triangles']} | {s['seam_pairs']} | "
              f"{s['crosspoint_vertices']} | {s['min_angle_band_deg']:.1f} | {s['build_s']:.2f} |")
    return result


def _summary(template: Template, dpi: float, levels: list[dict[str, object]], seconds: float) -> dict[str, object]:
    pattern = template.pattern
    return {
        "garment": pattern.name,
        "panels": [p.name for p in pattern.panels],
        "panel_area_m2": float(sum(p.area() for p in pattern.panels)),
        "markers": template.layout.num_markers,
        "sheet_px": list(template.layout.size_px),
        "dpi": dpi,
        "levels": levels,
        "seconds": seconds,
    }


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m assets.garments",
        description="Garment templates: sewing pattern -> printable pattern texture and meshes at several "
        "resolutions whose vertices know their place on the printed fabric.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="build a template", formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    b.add_argument("garment", help=f"a default garment ({', '.join(DEFAULT_GARMENTS)}) or a pattern JSON "
                   "(this project's format or GarmentCode's specification)")
    b.add_argument("--out", type=Path, required=True, help="output folder")
    b.add_argument("--levels", default=",".join(str(v) for v in LEVELS_MM[:3]),
                   help="grid spacings in mm, comma-separated (the reference's levels: 12,4,2,1)")
    b.add_argument("--dpi", type=float, default=300.0, help="resolution of the pattern texture / print file")
    b.add_argument("--max-pixels", type=float, default=MAX_PIXELS,
                   help="refuse a pattern sheet of more pixels than this (its memory: 3 bytes a pixel, twice)")
    b.add_argument("--max-panel-m", type=float, default=MAX_PANEL_M,
                   help="refuse a panel that may reach further across than this, in metres (a wrong sagitta "
                   "or unit would otherwise be sampled and meshed at any size)")
    b.add_argument("--pitch-mm", type=float, default=PatternSpec.pitch_mm, help="crosspoint pitch")
    b.add_argument("--seed", type=int, default=PatternSpec.seed, help="marker codebook seed")
    b.add_argument("--formats", default="obj,ply", help=f"mesh files per level, from {','.join(FORMATS)}")
    b.add_argument("--flat", action="store_true", help="write meshes flat as printed instead of placed around the body")
    sub.add_parser("list", help="list the default garments")
    return parser


def list_defaults() -> None:
    for name in DEFAULT_GARMENTS:
        print(f"{name}: {', '.join(p.name for p in default_pattern(name).panels)}")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_cli(list_defaults if args.command == "list" else lambda: build(args))


if __name__ == "__main__":
    sys.exit(main())
