"""``python -m reconstruction video``: synchronise a capture of one video per camera, or split it into frames.

    python -m reconstruction video offsets capture/              # -> capture/offsets.json
    python -m reconstruction video offsets capture/ --cameras cameras.json --reference cam00 --max-offset 120
    python -m reconstruction video extract capture/ --out frames/ --first 0 --last 599

A capture folder holds one video per camera (``NAME.mp4``, or ``camII.mp4`` with --cameras; .avi .mov
.mkv .webm .m4v too), at one constant frame rate.  `offsets` estimates each camera's frame offset from
the motion all cameras see (`reconstruction.video_sync`: what it assumes and when it fails) and writes
``{"camera name": offset_frames}``: capture frame k is the camera's video frame k + offset.
``python -m reconstruction run --views capture/`` reads the videos with ``capture/offsets.json`` as
it reads folders of frames; write that file by hand when the offsets are known (a clapper, timecode).
`extract` writes every camera's capture frames as ``OUT/NAME/f000123.png`` in worker processes; an
interrupted run resumes where it stopped.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: "argparse._SubParsersAction") -> None:
    """Add ``video offsets`` and ``video extract`` to the reconstruction CLI's subcommands."""
    from assets.cli import add_progress, add_workers

    video = sub.add_parser("video", help="frame offsets of a capture of one video per camera; its frames as "
                           "images", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    action = video.add_subparsers(dest="video_command", required=True)
    offsets = action.add_parser("offsets", help="estimate each camera's frame offset from the motion in its video")
    extract = action.add_parser("extract", help="every camera's capture frames as PNG images, resumable")
    for p in (offsets, extract):
        p.add_argument("views", type=Path, help="the capture folder: one video per camera")
        p.add_argument("--cameras", type=Path, help="calibration naming the cameras (cameras.json or any format "
                       "of `cameras convert`; default: every video in the folder, named by its file name)")
        add_workers(p, "worker processes decoding the videos (default: one per CPU core)")
        add_progress(p)
    offsets.add_argument("--out", type=Path, help="offsets JSON to write (default: VIEWS/offsets.json)")
    offsets.add_argument("--reference", help="camera whose offset is 0 (default: the first)")
    offsets.add_argument("--max-offset", type=int, metavar="FRAMES", help="largest offset to consider, in frames "
                         "(default: any that leaves half of the shortest video overlapping)")
    offsets.add_argument("--accept", action="store_true", help="write the offsets even when some are not "
                         "confident (correlation < 0.5 or margin < 0.1)")
    extract.add_argument("--out", type=Path, required=True, help="folder to write OUT/NAME/f000123.png into")
    extract.add_argument("--offsets", type=Path, help="offsets JSON (default: VIEWS/offsets.json if there, else none)")
    extract.add_argument("--first", type=int, help="first capture frame (default: the first all videos hold)")
    extract.add_argument("--last", type=int, help="last capture frame (default: the last all videos hold)")


def main(args: argparse.Namespace) -> int:
    """Run ``video offsets`` or ``video extract`` parsed by `add_parser`."""
    from assets.cli import progress, run_cli

    def action() -> None:
        from reconstruction.video_extract import extract_frames, find_videos
        from reconstruction.video_sync import estimate_offsets, overlap, read_offsets, write_offsets

        names = None
        if args.cameras:
            from reconstruction.calibration_formats import read_calibration

            names = [camera.name for camera in read_calibration(args.cameras)]
        videos = find_videos(args.views, names)
        if args.video_command == "offsets":
            estimates = estimate_offsets(videos, args.reference, args.max_offset, args.workers, progress(args))
            print(f"{'camera':<16} {'offset':>6} {'correlation':>11} {'margin':>6}")
            for name, e in estimates.items():
                print(f"{name:<16} {e.offset:>+6d} {e.correlation:>11.3f} {e.margin:>6.3f}"
                      f"{'' if e.confident else '  not confident'}")
            doubtful = [name for name, e in estimates.items() if not e.confident]
            if doubtful and not args.accept:
                raise RuntimeError(f"offsets of {doubtful} are not confident: nothing written (check the videos "
                                   f"share motion, narrow --max-offset, or --accept to write them anyway)")
            out = write_offsets(args.out or args.views / "offsets.json", {n: e.offset for n, e in estimates.items()})
            print(f"offsets of {len(estimates)} cameras written to {out}")
            return
        path = args.offsets or (args.views / "offsets.json")
        offsets = read_offsets(path, list(videos)) if args.offsets or path.is_file() else {}
        frames = None
        if args.first is not None or args.last is not None:
            from reconstruction.video import probe

            held = overlap({n: probe(p).num_frames for n, p in videos.items()}, {n: offsets.get(n, 0) for n in videos})
            first = held.start if args.first is None else args.first
            frames = range(first, (held.stop - 1 if args.last is None else args.last) + 1)
        written = extract_frames(videos, args.out, offsets, frames, args.workers, progress(args))
        print(f"{written} images written to {args.out} (those already there were kept)")

    return run_cli(action, failures=(RuntimeError,))
