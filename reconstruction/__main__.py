"""python -m reconstruction: calibrated multi-view images -> a complete, intersection-free garment sequence.

    python -m reconstruction run --cameras cameras.json --views DIR --template shirt --out DIR \\
        --localizer localizer.pt --recognizer recognizer.pt --crosspoints crosspoints.pt
    python -m reconstruction run --views out/capture --template shirt --out out/rec \\
        --detections groundtruth --noise 0.3 --evaluate          # a factory capture, no networks
    python -m reconstruction run --views out/capture --template shirt --out out/rec --evaluate \\
        --localizer localizer.pt --recognizer recognizer.pt --crosspoints crosspoints.pt  # networks, evaluated
    python -m reconstruction detect | triangulate | refine | export | evaluate --out DIR ...

Each stage writes into --out and skips what is already there, so an interrupted run resumes and a
later stage reruns alone (the folder layout is in `reconstruction.pipeline`).  Each records the
settings it was run with there, and a rerun with other settings is refused, naming them: use another
--out.  `--detections groundtruth` takes the 2D observations from a factory capture's ground truth
(`--views` is the capture folder) with `--noise` pixels and `--dropout`; every output names its source.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from assets.cli import (add_completion_options, add_crosspoint_options, add_device, add_networks, add_out,
                        add_progress, completion_options, crosspoint_options, localizer_scale_arg, networks_of,
                        progress, run_cli)
from reconstruction import cameras_cli, video_cli


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


def build_parser() -> argparse.ArgumentParser:
    from assets.cameras import MAX_IMAGE_PIXELS
    from networks.config import KEEP_OWN_CELLS, NEIGHBOUR_DEGREE, NEIGHBOUR_SIGMA_SIDES, SMOOTH_CROSSPOINTS_PX  # torch-free

    parser = argparse.ArgumentParser(prog="python -m reconstruction", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    def settings(p: argparse.ArgumentParser) -> None:
        p.add_argument("--views", required=True, help="a folder of frames per camera (or a video each, with "
                       "offsets.json when they started apart: `video offsets`), or with "
                       "--detections groundtruth a factory capture folder")
        p.add_argument("--cameras", help="cameras.json or OpenCV calibration YAML (default: the capture's)")
        p.add_argument("--template", required=True, help="default garment name, pattern JSON or template .npz")
        p.add_argument("--max-image-pixels", type=int, default=MAX_IMAGE_PIXELS, metavar="N",
                       help="refuse cameras whose images are larger than N pixels (width x height; default %(default)s)")
        p.add_argument("--level", type=int, default=12, help="template level (mm) the crosspoints are located on")
        p.add_argument("--detections", choices=("networks", "groundtruth"), default="networks")
        add_networks(p, help_prefix="networks mode: ")
        p.add_argument("--noise", type=float, default=0.0, help="ground-truth mode: pixel noise sigma")
        p.add_argument("--dropout", type=float, default=0.0, help="ground-truth mode: fraction of crosspoints dropped")
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--frames", help="frames to use, e.g. 120-131 or 120,125 (default: all)")
        add_device(p, help="networks mode: cpu, cuda or cuda:N (default: a GPU when there is one); several, "
                   "comma-separated (cuda:0,cuda:1), shard the frames over them, one process each; `run` "
                   "also refines on the first (default: the CPU)")
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
        add_out(p, help="the reconstruction folder")
        add_progress(p)

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
    add_device(refine, help="where Newton's VBD solves run: cpu (the default), cuda or cuda:N")
    export = sub.add_parser("export", help="npz, PLY/OBJ per frame, PC2 and a review .blend")
    common(export)
    export.add_argument("--texture", help="the garment's pattern texture PNG for the OBJ and .blend materials")
    for p in (run, export):
        p.add_argument("--fps", type=float, default=120.0, help="frames per second of the capture")
    evaluate = sub.add_parser("evaluate", help="accuracy against a factory capture's ground truth")
    common(evaluate)
    evaluate.add_argument("--groundtruth", required=True, help="the factory capture folder")
    cameras_cli.add_parser(sub)
    video_cli.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "cameras":  # calibration files and rig calibration: reconstruction/cameras_cli.py
        return cameras_cli.main(args)
    if args.command == "video":  # offsets and frames of one video per camera: reconstruction/video_cli.py
        return video_cli.main(args)
    out, bars = Path(args.out), progress(args)

    def action() -> None:
        from reconstruction import pipeline

        if args.command in ("run", "detect"):
            settings, cameras = _run_settings(args)
            if args.command == "run":
                evaluation = pipeline.run(out, args.views, settings, cameras, _frames(args.frames), args.device,
                                          _triangulation(args), _refinement(args), args.start_frame, fps=args.fps,
                                          evaluate_against=args.views if args.evaluate else None, progress=bars,
                                          max_image_pixels=args.max_image_pixels)
                print(f"reconstruction in {out} ({settings.source}): exports in {out / 'export'}")
                _print_evaluation(evaluation)
                return
            pipeline.start(out, settings)
            frames = pipeline.detect(out, args.views, cameras, _frames(args.frames), args.device, bars,
                                     max_image_pixels=args.max_image_pixels)
            print(f"detections of {len(frames)} frames in {out / 'detections'} ({settings.source})")
        elif args.command == "triangulate":
            paths = pipeline.triangulate(out, config=_triangulation(args), progress=bars)
            print(f"captured points of {len(paths)} frames in {out / 'points'}")
        elif args.command == "refine":
            path = pipeline.refine(out, config=_refinement(args), start_frame=args.start_frame, progress=bars,
                                   frames=_frames(args.frames), device=args.device)
            print(f"refined sequence {path}")
        elif args.command == "export":
            print(f"exports in {pipeline.export(out, texture=args.texture, fps=args.fps, progress=bars)}")
        else:
            _print_evaluation(pipeline.evaluate(out, args.groundtruth))

    return run_cli(action, failures=(ValueError, RuntimeError))


def _run_settings(args: argparse.Namespace):
    """The `pipeline.RunSettings` and the cameras (or None: the views folder's) of `run`/`detect`."""
    from reconstruction import pipeline

    cameras = None
    if args.cameras:
        from reconstruction.cameras import read_cameras

        cameras = read_cameras(args.cameras, max_image_pixels=args.max_image_pixels)
    initial = args.initial_shape
    if initial is None and (Path(args.views) / "sim" / "dressed.npz").is_file():
        initial = Path(args.views) / "sim" / "dressed.npz"  # a factory capture's dressed garment
    settings = pipeline.RunSettings(template=args.template, level_mm=args.level, detections=args.detections,
                                    noise_px=args.noise, dropout=args.dropout, seed=args.seed,
                                    checkpoints=tuple(str(Path(c).resolve()) for c in networks_of(args)),
                                    initial_shape=str(Path(initial).resolve()) if initial else "",
                                    localizer_scale=args.localizer_scale, grow_missing=not args.no_grow,
                                    **crosspoint_options(args), **completion_options(args))
    return settings, cameras


def _triangulation(args: argparse.Namespace):
    from reconstruction.triangulation import TriangulationConfig

    return TriangulationConfig(neighbours=None) if args.no_neighbour_check else TriangulationConfig()


def _refinement(args: argparse.Namespace):
    from reconstruction.refinement import RefineConfig

    levels = _levels(args.levels)
    return RefineConfig(levels_mm=levels) if levels else RefineConfig()


def _print_evaluation(evaluation: dict | None) -> None:
    for key, value in (evaluation or {"summary": {}})["summary"].items():
        meaning = evaluation["definitions"].get(key)
        print(f"{key}: {value}" + (f"  ({meaning})" if meaning else ""))


if __name__ == "__main__":
    sys.exit(main())
