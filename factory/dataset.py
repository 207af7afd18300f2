"""Datasets: simulation -> Blender renders -> ground truth, and the factory's dataset CLI.

    python -m factory.dataset build --garment shirt --motions walk,run --frames 8 --variations 5 --out out/ds
    python -m factory.dataset build ... --shard 0/4          # a deterministic quarter of the images
    python -m factory.dataset build ... --betas 0.5,0.5,0.8  # another body shape (the body's shape_names)
    python -m factory.dataset build ... --backend ray --workers 8   # Ray tasks (`factory.raybackend`)
    python -m factory.dataset build --recipe modules_reader --out out/datasets/modules_reader  # `factory.recipe`
    python -m factory.dataset capture --garment shirt --motion walk --frames 12 --cameras 8 --out out/cap
    python -m factory.dataset preview out/ds --out out/ds/contact_sheet.png
    python -m factory.dataset merge out/ds --train out/ds_more --out out/all   # more training images (`factory.merge`)

Training dataset (`build`), as in the reference: one fixed camera; per simulation frame
`variations` images (5), each with a random rotation about the vertical and a small tilt and
translation of garment and body, an environment chosen from 10 (Blender's eight bundled HDRIs and two
sky worlds) at a random rotation and strength, and jittered cloth and skin materials.  Every random
choice comes from a generator seeded by (seed, motion, frame, variation), so any image can be remade
alone.  Frames are split into train, validation and test at 22:2:1 **by simulation frame**: the
variations of one frame never straddle splits (`factory.plan`).

Layout of a dataset folder:
  config.json                  the build's settings and input files' digests (a rerun with others is
                               refused, naming them: `assets.fileio.record_stage`)
  template.npz, texture.png    the garment template and its pattern texture at `texture_dpi`
  sim/<motion>/                the simulations (`factory.simulate`; reused when already there)
  sim/dressings/<key>.npz      the dressed garment the motions' simulations share
  scenes/<motion>.npz          the frames to render: garment and body vertices
  jobs/<motion>-<shard>.json   render jobs (`factory.render`)
  images/<name>.png            RGB; <name>_depth.exr (Z, float32), <name>_camera.json (K, R, t);
                               render.json: the render settings they share (`factory.render`)
  gt/<name>.npz                ground truth of every marker (`assets.pattern.observation.ImageGroundTruth`)
  samples/<name>.npz           training arrays: the Marker Localizer's cell targets (`cells`), the
                               96 x 96 recognizer crops with their IDs, the 112 x 112 crosspoint crops
                               with the crosspoints' crop coordinates and visibility
  meta/<name>.json             one finished image (written last: an image is done when this exists)
  manifest.jsonl, splits.json  every finished image with its files, split, motion, frame, variation
                               and simulation (`factory.simulate.SimulationConfig.key()`)

The build itself (`factory.build`, its tasks `factory.shards`; `build --help`): one simulation task
per motion, then render + ground-truth tasks of `--shard-frames` frames; `--shard i/n` takes every
n-th image from the i-th, a killed run resumes where it stopped, several processes or machines
sharing the folder can work on one dataset at once, and `--backend ray` runs the tasks on a Ray
cluster (`factory.raybackend`).

Capture (`capture`, `factory.capture`): a calibrated ring of cameras around the subject renders every
frame of a sequence, with ground truth per image and the ground-truth garment sequence: the
synthetic capture reconstruction is tested and measured on.  Its `capture.json` records its settings
and input files' digests: a rerun renders only what is missing, and only for the same capture.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from assets.cli import add_device, add_out, add_progress, add_workers, progress, run_cli
from assets.fileio import load_json
import factory.build
import factory.merge
from factory.capture import capture
from factory.dressing import DressingParams
from factory.limits import Limits, add_limit_options, limits_from_args
from factory.plan import DatasetConfig, RenderSettings, check_betas
from factory.preview import preview
from factory.recipe import build_recipe
from factory.simulate import SimulationConfig

#: --device for Cycles: the shared vocabulary's names -> `RenderSettings.device`
RENDER_DEVICES = {"cpu": "CPU", "cuda": "GPU", "gpu": "GPU", "auto": "auto"}


def _resolution(text: str) -> tuple[int, int]:
    try:
        parts = [int(v) for v in text.lower().split("x")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must be N or WxH, got {text!r}") from None
    if len(parts) == 1:
        parts *= 2
    if len(parts) != 2 or min(parts) < 8:
        raise argparse.ArgumentTypeError(f"resolution must be N or WxH with sides >= 8, got {text!r}")
    return parts[0], parts[1]


def _shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"shard must be i/n, got {text!r}") from None
    return i, n


def _add_render_args(p: argparse.ArgumentParser, resolution: str) -> None:
    p.add_argument("--resolution", type=_resolution, default=_resolution(resolution), help="N or WxH pixels")
    p.add_argument("--engine", choices=("CYCLES", "EEVEE", "WORKBENCH"), default="CYCLES")
    p.add_argument("--samples", type=int, default=RenderSettings.samples)
    p.add_argument("--no-denoise", action="store_true")
    add_device(p, help="where Cycles renders: cpu, or cuda (gpu: the same; the first GPU backend Blender finds: "
               "OptiX, CUDA, HIP, oneAPI, Metal); default: a GPU when Blender finds one, else the CPU")
    p.add_argument("--texture-dpi", type=float, default=RenderSettings.texture_dpi)


def _add_simulation_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--level", type=int, default=DressingParams.level_mm,
                   help="template level (mm) the garment is simulated on (factory.simulate --level)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="built-in motions: speed multiplier (factory.simulate --speed)")
    p.add_argument("--betas", metavar="V,V,...",
                   help="the body's shape values, one per shape name (the default body: gender,weight,height, each "
                   "in [0, 1]); default: the motion's own shape, else the body's default")


def _check_sizes(args: argparse.Namespace, limits: Limits, last_frame: int, images_per_frame: tuple[str, int]) -> None:
    """The sizes a build or capture asks for within `limits`, before anything is made: image pixels,
    samples, the last simulation frame and (option, value) images per frame (variations or cameras)."""
    width, height = args.resolution
    limits.check("pixels", width * height, f"an image of {width} x {height} pixels", "--resolution")
    if args.samples < 1:
        raise ValueError(f"--samples: expected >= 1, got {args.samples}")
    limits.check("samples", args.samples, "the render samples", "--samples")
    limits.check("frames", last_frame, "the last simulation frame", "--frames")
    option, count = images_per_frame
    if count < 1:
        raise ValueError(f"{option}: expected >= 1, got {count}")
    limits.check(option.lstrip("-"), count, f"the number of {option.lstrip('-')}", option)


def _render_settings(args: argparse.Namespace) -> RenderSettings:
    device = RENDER_DEVICES.get((args.device or "auto").lower())
    if device is None:
        raise ValueError(f"--device: expected one of {', '.join(RENDER_DEVICES)} for Cycles, got {args.device!r}")
    return RenderSettings(resolution=tuple(args.resolution), engine=args.engine, samples=args.samples,
                          denoise=not args.no_denoise, device=device, texture_dpi=args.texture_dpi)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m factory.dataset", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="simulate, render and annotate a training dataset",
                       description=factory.build.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    b.add_argument("--recipe", help="build a recipe's data (networks/recipes/NAME.toml, or a .toml file): its "
                   "training and held-out parts, each a dataset folder under --out (`factory.recipe`); the "
                   "recipe gives what --garment .. --texture-dpi give otherwise")
    b.add_argument("--train-only", action="store_true", help="--recipe: its training parts only")
    b.add_argument("--garment", help="the garment (required without --recipe)")
    b.add_argument("--motions", help="comma-separated motion names or files (required without --recipe)")
    b.add_argument("--body", default="default")
    b.add_argument("--frames", type=int, default=DatasetConfig.frames, help="frames per motion")
    b.add_argument("--frame-step", type=int, default=DatasetConfig.frame_step, help="simulation frames between them")
    b.add_argument("--frame-list", help="explicit comma-separated simulation frames instead")
    b.add_argument("--variations", type=int, default=DatasetConfig.variations)
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--fill", type=float, default=DatasetConfig.fill,
                   help="how much of the narrower image side the garment fills (default %(default)s); smaller: "
                   "smaller markers")
    b.add_argument("--fov", type=float, default=DatasetConfig.fov_deg,
                   help="the camera's horizontal field of view, degrees (default %(default)s)")
    _add_simulation_args(b)
    b.add_argument("--shard", type=_shard, default=(0, 1), help="i/n: this process's share of the images")
    b.add_argument("--backend", choices=factory.build.BACKENDS, default="local",
                   help="local: every task in this process; ray: Ray tasks (pip install '.[ray]')")
    b.add_argument("--address", help="ray: the cluster to join (e.g. HEAD_IP:6379 or auto); default: start a "
                   "local Ray instance")
    add_workers(b, help="ray: tasks at once on the local Ray instance it starts (default: one per core); "
                "without --backend ray one process works alone (--shard i/n spreads a build over processes)")
    b.add_argument("--shard-frames", type=int, default=1,
                   help="simulation frames (with their variations) per render + ground-truth task")
    b.add_argument("--reuse-simulation", action="append", default=[], metavar="MOTION=DIR",
                   help="a finished `factory.simulate` folder for a motion (repeatable), made with the same "
                   "--garment, --body, --betas, --seed, --level and --speed")
    add_out(b, "the dataset folder (a rerun resumes it; other settings are refused)")
    add_progress(b)
    _add_render_args(b, "512")
    add_limit_options(b, ("pixels", "samples", "frames", "variations"))
    c = sub.add_parser("capture", help="render a sequence from a calibrated ring of cameras")
    c.add_argument("--garment", required=True)
    c.add_argument("--motion", required=True)
    c.add_argument("--body", default="default")
    c.add_argument("--frames", type=int, default=12)
    c.add_argument("--first-frame", type=int, help="default: the first frame after the dressing transition")
    c.add_argument("--cameras", type=int, default=8)
    c.add_argument("--radius", type=float, default=3.0, help="ring radius (m)")
    c.add_argument("--height", type=float, default=1.3, help="ring height (m), about chest height")
    c.add_argument("--seed", type=int, default=0)
    _add_simulation_args(c)
    c.add_argument("--reuse-simulation", type=Path, metavar="DIR",
                   help="a finished `factory.simulate` folder made with the same options")
    add_out(c, "the capture folder (a rerun renders only what is missing; other settings are refused)")
    add_progress(c)
    _add_render_args(c, "1920x1080")
    add_limit_options(c, ("pixels", "samples", "frames", "cameras"))
    m = sub.add_parser("merge", help="merge dataset folders into one (more training images beside a held-out split)",
                       description=factory.merge.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    m.add_argument("sources", type=Path, nargs="*", help="dataset folders whose splits are kept")
    m.add_argument("--train", type=Path, action="append", default=[], metavar="SRC",
                   help="a dataset folder whose images all go to the train split (repeatable)")
    add_out(m, "the merged dataset folder")
    add_progress(m)
    v = sub.add_parser("preview", help="contact sheet of a dataset or capture folder")
    v.add_argument("folder", type=Path)
    add_out(v, "the contact sheet PNG")
    v.add_argument("--count", type=int, default=6)
    args = parser.parse_args(argv)
    args.out = Path(args.out)

    def action() -> None:
        if args.command == "build" and args.workers is not None and args.backend != "ray":
            raise ValueError("--workers sets the Ray tasks at once: give --backend ray (or --shard i/n to spread a "
                             "local build over processes)")
        if args.command == "build" and args.recipe is not None:
            if args.garment is not None or args.motions is not None:
                raise ValueError("--recipe gives the garments and motions; leave out --garment and --motions")
            started = time.perf_counter()
            folders = build_recipe(args.recipe, args.out, args.shard, holdout=not args.train_only,
                                   progress=progress(args), backend=args.backend, address=args.address,
                                   workers=args.workers, shard_frames=args.shard_frames)
            print(f"recipe {args.recipe}: {len(folders)} dataset folders in {args.out} "
                  f"({time.perf_counter() - started:.0f} s); {args.out / 'recipe.json'} lists them")
        elif args.command == "build":
            if args.garment is None or args.motions is None:
                raise ValueError("give --garment and --motions, or --recipe")
            try:
                frame_list = tuple(int(f) for f in args.frame_list.split(",")) if args.frame_list else None
            except ValueError:
                raise ValueError(f"--frame-list: expected comma-separated frame numbers, got {args.frame_list!r}") \
                    from None
            if args.frames < 1 or args.frame_step < 1 or min(frame_list or [0]) < 0:
                raise ValueError("--frames and --frame-step must be >= 1 and --frame-list's frames >= 0")
            transition = int(round(SimulationConfig(args.garment, "").transition_seconds * 120))
            last = max(frame_list) if frame_list else transition + args.frames * args.frame_step
            _check_sizes(args, limits_from_args(args), last, ("--variations", args.variations))
            config = DatasetConfig(garment=args.garment, motions=tuple(m for m in args.motions.split(",") if m),
                                   body=args.body, betas=check_betas(args.betas, args.body, "--betas"),
                                   frames=args.frames, frame_step=args.frame_step,
                                   frame_list=frame_list, variations=args.variations, seed=args.seed,
                                   level_mm=args.level, motion_speed=args.speed, render=_render_settings(args),
                                   fov_deg=args.fov, fill=args.fill)
            started = time.perf_counter()
            reuse = dict(item.split("=", 1) for item in args.reuse_simulation if "=" in item)
            if len(reuse) != len(args.reuse_simulation):
                raise ValueError(f"--reuse-simulation takes MOTION=DIR, got {args.reuse_simulation}")
            manifest = factory.build.build(config, args.out, args.shard, progress=progress(args), simulations=reuse,
                                           backend=args.backend, address=args.address, workers=args.workers,
                                           shard_frames=args.shard_frames)
            entries = manifest.read_text().splitlines()
            timing = load_json(args.out / "timing.json")
            print(f"{len(entries)} images in {manifest} ({timing['images']} made now, {timing['retried']} failed "
                  f"task attempts retried, {time.perf_counter() - started:.0f} s); "
                  f"contact sheet {args.out / 'contact_sheet.png'}")
        elif args.command == "capture":
            if args.frames < 1 or (args.first_frame or 0) < 0:
                raise ValueError("--frames must be >= 1 and --first-frame >= 0")
            first = int(round(SimulationConfig(args.garment, "").transition_seconds * 120)) \
                if args.first_frame is None else args.first_frame
            _check_sizes(args, limits_from_args(args), first + args.frames, ("--cameras", args.cameras))
            folder = capture(args.garment, args.motion, args.out, frames=args.frames, first_frame=args.first_frame,
                             cameras=args.cameras, resolution=tuple(args.resolution),
                             render=_render_settings(args), body=args.body, radius=args.radius,
                             camera_height=args.height, seed=args.seed, simulation=args.reuse_simulation,
                             level_mm=args.level, motion_speed=args.speed, progress=progress(args),
                             betas=check_betas(args.betas, args.body, "--betas"))
            print(f"capture in {folder}: cameras.json, garment.npz, {args.cameras} camera folders; "
                  f"contact sheet {folder / 'contact_sheet.png'}")
        elif args.command == "merge":
            sources = [factory.merge.Source(f) for f in args.sources] + [factory.merge.Source(f, True) for f in args.train]
            manifest = factory.merge.merge(args.out, sources, progress(args))
            print(f"{len(manifest.read_text().splitlines())} images in {manifest}")
        else:
            print(preview(args.folder, args.out, args.count))

    return run_cli(action, failures=(ValueError, RuntimeError))


if __name__ == "__main__":
    sys.exit(main())
