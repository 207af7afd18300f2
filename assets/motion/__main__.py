"""Motions on bodies from the command line.

    python -m assets.motion list
    python -m assets.motion preview walk --body default --out out/walk        # PNG + posed sequence
    python -m assets.motion preview capture.npz --body SMPL_NEUTRAL.npz --out out/amass --meshes obj
    python -m assets.motion convert 01_01.bvh --out 01_01_motion.npz          # BVH or AMASS -> motion
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from assets.body import load_body
from assets.cli import run_cli
from assets.fileio import save_json, staged_outputs
from assets.motion.export import preview_frames, render_preview, save_posed_sequence, write_frame_meshes
from assets.motion.motion import (
    MAX_FRAMES,
    SIMULATION_FPS,
    TRANSITION_SECONDS,
    pose_motion,
    resample,
    with_transition,
)
from assets.motion.sources import load_motion

log = logging.getLogger("assets.motion")


def _motion_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, default=None, help="length of a built-in motion (default: its own)")
    parser.add_argument("--speed", type=float, default=1.0, help="built-in motions: cycle speed multiplier")
    parser.add_argument("--amplitude", type=float, default=1.0, help="built-in motions: joint angle scale")
    parser.add_argument("--fps", type=float, default=SIMULATION_FPS, help="resample to this rate (default 120)")
    _max_frames_arg(parser)


def _max_frames_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--max-frames", type=int, default=MAX_FRAMES,
                        help="refuse motions of more frames, read or resampled (default %(default)s: 10 min at 120 Hz)")


def preview(args: argparse.Namespace) -> None:
    """Write preview.png, motion.npz, body_sequence.npz, summary.json (and meshes/) into --out, all
    replaced together or, on any error, none of them."""
    if args.frames < 1:
        raise ValueError(f"--frames must be at least 1, got {args.frames}")
    body = load_body(args.body)
    motion = load_motion(args.motion, body, args.seconds, args.speed, args.amplitude, args.fps, args.max_frames)
    motion = resample(motion, args.fps, args.max_frames)
    if args.transition != "none":
        motion = with_transition(motion, args.transition, args.transition_seconds, max_frames=args.max_frames)
    out = Path(args.out)
    posed = pose_motion(body, motion)
    frames = preview_frames(args.frames, motion.num_frames)
    with staged_outputs(out) as stage:
        motion.save(stage / "motion.npz")
        save_posed_sequence(stage / "body_sequence.npz", posed, motion.fps, body=body.name, motion=motion.name)
        render_preview(stage / "preview.png", posed, frames, title=f"{motion.name} on {body.name} body")
        meshes = write_frame_meshes(stage / "meshes", posed, args.meshes) if args.meshes else []
        save_json(stage / "summary.json", {
            "motion": motion.name, "source": motion.source, "body": body.name, "frames": motion.num_frames,
            "fps": motion.fps, "seconds": motion.duration, "preview_frames": frames.tolist(),
        })  # fmt: skip
    # Meshes of an earlier, longer run would otherwise sit beside this run's.
    kept = {p.name for p in meshes}
    for stale in sorted((out / "meshes").glob("frame_*")) if args.meshes else ():
        if stale.name not in kept:
            stale.unlink()
    log.info("%s: %d frames at %g Hz on the %s body -> %s", motion.name, motion.num_frames, motion.fps, body.name, out)


def convert(args: argparse.Namespace) -> None:
    body = load_body(args.body) if args.body else None
    motion = load_motion(args.file, body, max_frames=args.max_frames)
    if args.fps:
        motion = resample(motion, args.fps, args.max_frames)
    motion.save(args.out)
    log.info("%s: %d frames at %g Hz -> %s", args.file, motion.num_frames, motion.fps, args.out)


def list_motions(args: argparse.Namespace) -> None:
    from assets.motion.builtin import BUILTIN_MOTIONS

    for name in sorted(BUILTIN_MOTIONS):
        print(f"{name:12s} {BUILTIN_MOTIONS[name].seconds:5.1f} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m assets.motion", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("preview", help="pose a body through a motion; write a PNG preview and the sequence")
    p.add_argument("motion", help="built-in motion name, AMASS .npz, saved motion .npz or .bvh")
    p.add_argument("--body", default="default", help="'default' (free body) or an SMPL-family model file")
    p.add_argument("--out", required=True, help="output folder")
    _motion_args(p)
    p.add_argument("--transition", choices=("T", "A", "none"), default="A",
                   help="prepend a transition from this dressing pose (default A, as the simulator does)")
    p.add_argument("--transition-seconds", type=float, default=TRANSITION_SECONDS)
    p.add_argument("--frames", type=int, default=6, help="frames drawn in the preview")
    p.add_argument("--meshes", choices=("obj", "ply"), help="also write one mesh per frame")
    p.set_defaults(action=preview)
    c = sub.add_parser("convert", help="convert a BVH or AMASS file to a motion .npz (Z up, SMPL 24 joints)")
    c.add_argument("file", help=".bvh or AMASS .npz")
    c.add_argument("--out", required=True, help="motion .npz to write")
    c.add_argument("--body", help="retarget BVH onto / take AMASS pelvis offsets from this body")
    c.add_argument("--fps", type=float, help="resample to this rate (default: keep the file's)")
    _max_frames_arg(c)
    c.set_defaults(action=convert)
    ls = sub.add_parser("list", help="list the built-in motions")
    ls.set_defaults(action=list_motions)
    args = parser.parse_args(argv)
    return run_cli(lambda: args.action(args))


if __name__ == "__main__":
    sys.exit(main())
