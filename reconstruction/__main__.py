"""python -m reconstruction: calibrated multi-view images -> a complete, intersection-free garment sequence.

    python -m reconstruction run --cameras cameras.json --views DIR --template shirt --out DIR \\
        --checkpoints localizer.pt recognizer.pt crosspoints.pt
    python -m reconstruction run --views out/capture --template shirt --out out/rec \\
        --detections groundtruth --noise 0.3 --evaluate          # a factory capture, no networks
    python -m reconstruction run --views out/capture --template shirt --out out/rec \\
        --checkpoints localizer.pt recognizer.pt crosspoints.pt --evaluate   # networks, evaluated
    python -m reconstruction detect | triangulate | refine | export | evaluate --out DIR ...

Each stage writes into --out and skips what is already there, so an interrupted run resumes and a
later stage reruns alone (the folder layout is in `reconstruction.pipeline`).  `--detections
groundtruth` takes the 2D observations from a factory capture's ground truth (`--views` is the capture
folder) with `--noise` pixels and `--dropout`; every output names its source.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from assets.cli import (add_completion_options, add_crosspoint_options, completion_options, crosspoint_options,
                        localizer_scale_arg, run_cli)
from reconstruction import cameras_cli


def _frames(text: str | None) -> list[int] | None:
    if not text:
        return None
    frames = []
    for part in text.split(","):
        first, _, last = part.partition("-")
        frames += list(range(int(first), int(last or first) + 1))
    return frames


def _levels(text: str | None) -> tuple[int, ...] | None:
    return tuple(int(v) for v in text.split(",")) if text else None


def _check_factory_capture(views: str) -> None:
    """Refuse `views` unless it is a factory capture (cameras, ground truth per camera, garment.npz)."""
    from reconstruction.groundtruth import GroundTruthCapture

    try:
        GroundTruthCapture(views)
    except ValueError as exc:
        raise ValueError(f"--evaluate needs a factory capture as --views: {exc}") from exc
    if not (Path(views) / "garment.npz").is_file():
        raise ValueError(f"--evaluate needs a factory capture as --views: {views} has no garment.npz")


def build_parser() -> argparse.ArgumentParser:
    from assets.cameras import MAX_IMAGE_PIXELS
    from networks.config import KEEP_OWN_CELLS, NEIGHBOUR_DEGREE, NEIGHBOUR_SIGMA_SIDES, SMOOTH_CROSSPOINTS_PX  # torch-free

    parser = argparse.ArgumentParser(prog="python -m reconstruction", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    def settings(p: argparse.ArgumentParser) -> None:
        p.add_argument("--views", required=True, help="a folder of frames per camera (or a video each), or with "
                       "--detections groundtruth a factory capture folder")
        p.add_argument("--cameras", help="cameras.json or OpenCV calibration YAML (default: the capture's)")
        p.add_argument("--template", required=True, help="default garment name, pattern JSON or template .npz")
        p.add_argument("--max-image-pixels", type=int, default=MAX_IMAGE_PIXELS, metavar="N",
                       help="refuse cameras whose images are larger than N pixels (width x height; default %(default)s)")
        p.add_argument("--level", type=int, default=12, help="template level (mm) the crosspoints are located on")
        p.add_argument("--detections", choices=("networks", "groundtruth"), default="networks")
        p.add_argument("--checkpoints", nargs=3, metavar=("LOCALIZER", "RECOGNIZER", "CROSSPOINTS"), default=(),
                       help="the three networks' checkpoints (networks mode)")
        p.add_argument("--noise", type=float, default=0.0, help="ground-truth mode: pixel noise sigma")
        p.add_argument("--dropout", type=float, default=0.0, help="ground-truth mode: fraction of crosspoints dropped")
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--frames", help="frames to use, e.g. 120-131 or 120,125 (default: all)")
        p.add_argument("--device", help="networks mode: cuda or cpu (default: a GPU when there is one); several, "
                       "comma-separated (cuda:0,cuda:1), shard the frames over them, one process each")
        p.add_argument("--localizer-scale", type=localizer_scale_arg, default="auto",
                       help="networks mode: the marker localizer sees the views resized by this factor, so that "
                       "markers are 16 to 32 px across there (0.5 for 32 to 64 px markers), or 'auto' (the "
                       "default): chosen per view from a first pass's marker sizes")
        p.add_argument("--no-grow", action="store_true",
                       help="networks mode: do not add the markers the localizer missed next to fully observed "
                       "ones (default: add them; they raise the captured fraction, at a higher error p95)")
        add_crosspoint_options(p, SMOOTH_CROSSPOINTS_PX, prefix="networks mode: ")
        add_completion_options(p, KEEP_OWN_CELLS, (NEIGHBOUR_SIGMA_SIDES, NEIGHBOUR_DEGREE), prefix="networks mode: ")
        p.add_argument("--initial-shape", help="a penetration-free garment shape npz (positions, meta.level_mm) "
                       "the post-processing starts from (default: a factory capture's sim/dressed.npz when "
                       "--views is one, else the template's placement pose)")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--out", type=Path, required=True, help="the reconstruction folder")
        p.add_argument("--quiet", action="store_true", help="no progress bars")

    def refine_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--levels", help="refine levels, coarse to fine, mm (default: the reference's hierarchy)")
        p.add_argument("--start-frame", type=int, help="index of the frame solved first (default: the most captured)")

    run = sub.add_parser("run", help="every stage: detect, triangulate, refine, export (and evaluate)")
    settings(run), common(run), refine_options(run)
    run.add_argument("--evaluate", action="store_true", help="evaluate against the ground truth of --views, which "
                     "must then be a factory capture (either detection mode)")
    detect = sub.add_parser("detect", help="detections per camera and frame")
    settings(detect), common(detect)
    triangulate = sub.add_parser("triangulate", help="captured 3D points per frame")
    common(triangulate)
    for p in (run, triangulate):
        p.add_argument("--no-neighbour-check", action="store_true",
                       help="keep the triangulated points that no other marker's crosspoints confirm in 3D "
                       "(reconstruction.consistency; on by default: it removes wrong-ID points)")
    refine = sub.add_parser("refine", help="Newton VBD post-processing -> sequence.npz")
    common(refine), refine_options(refine)
    refine.add_argument("--frames", help="refine a window of the triangulated frames, e.g. 120-131 (default: all)")
    export = sub.add_parser("export", help="npz, PLY/OBJ per frame, PC2 and a review .blend")
    common(export)
    export.add_argument("--texture", help="the garment's pattern texture PNG for the OBJ and .blend materials")
    for p in (run, export):
        p.add_argument("--fps", type=float, default=120.0, help="frames per second of the capture")
    evaluate = sub.add_parser("evaluate", help="accuracy against a factory capture's ground truth")
    common(evaluate)
    evaluate.add_argument("--groundtruth", required=True, help="the factory capture folder")
    cameras_cli.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "cameras":  # calibration files and rig calibration: reconstruction/cameras_cli.py
        return cameras_cli.main(args)

    def action() -> None:
        from reconstruction import pipeline

        progress = not args.quiet
        if args.command == "run" and args.evaluate:
            _check_factory_capture(args.views)  # refused before any stage runs
        if args.command in ("run", "detect"):
            cameras = None
            if args.cameras:
                from reconstruction.cameras import read_cameras

                cameras = read_cameras(args.cameras, max_image_pixels=args.max_image_pixels)
            initial = args.initial_shape
            if initial is None and (Path(args.views) / "sim" / "dressed.npz").is_file():
                initial = Path(args.views) / "sim" / "dressed.npz"  # a factory capture's dressed garment
            settings = pipeline.RunSettings(template=args.template, level_mm=args.level, detections=args.detections,
                                            noise_px=args.noise, dropout=args.dropout, seed=args.seed,
                                            checkpoints=tuple(str(Path(c).resolve()) for c in args.checkpoints),
                                            initial_shape=str(Path(initial).resolve()) if initial else "",
                                            localizer_scale=args.localizer_scale, grow_missing=not args.no_grow,
                                            **crosspoint_options(args),
                                            **completion_options(args))
            pipeline.start(args.out, settings)
            frames = pipeline.detect(args.out, args.views, cameras, _frames(args.frames), args.device, progress,
                                     max_image_pixels=args.max_image_pixels)
            print(f"detections of {len(frames)} frames in {args.out / 'detections'} ({settings.source})")
        if args.command in ("run", "triangulate"):
            from reconstruction.triangulate import TriangulationConfig

            config = TriangulationConfig(neighbours=None) if args.no_neighbour_check else TriangulationConfig()
            paths = pipeline.triangulate(args.out, config=config, progress=progress)
            print(f"captured points of {len(paths)} frames in {args.out / 'points'}")
        if args.command in ("run", "refine"):
            from reconstruction.refine import RefineConfig

            levels = _levels(args.levels)
            config = RefineConfig(levels_mm=levels) if levels else RefineConfig()
            window = _frames(args.frames) if args.command == "refine" else None
            path = pipeline.refine(args.out, config=config, start_frame=args.start_frame, progress=progress,
                                   frames=window)
            print(f"refined sequence {path}")
        if args.command in ("run", "export"):
            texture = getattr(args, "texture", None)
            if texture is None and args.command == "run" and (Path(args.views) / "texture.png").is_file():
                texture = Path(args.views) / "texture.png"  # a factory capture's pattern texture
            print(f"exports in {pipeline.export(args.out, texture=texture, fps=args.fps, progress=progress)}")
        if args.command == "evaluate" or args.command == "run" and args.evaluate:
            summary = pipeline.evaluate(args.out, args.groundtruth if args.command == "evaluate" else args.views)
            for key, value in summary["summary"].items():
                meaning = summary["definitions"].get(key)
                print(f"{key}: {value}" + (f"  ({meaning})" if meaning else ""))

    return run_cli(action, failures=(ValueError, RuntimeError))


if __name__ == "__main__":
    sys.exit(main())
