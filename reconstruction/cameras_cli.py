"""``python -m reconstruction cameras``: calibration files in and out, and rig calibration.

    python -m reconstruction cameras convert calib/ cameras.json              # EasyMocap intri/extri.yml -> ours
    python -m reconstruction cameras convert cameras.json sparse/ --format colmap
    python -m reconstruction cameras convert calibration.toml rig.json --in-units mm
    python -m reconstruction cameras calibrate --board 9x7,0.05,0.037,DICT_4X4_50 --images boards/ \\
        --out cameras.json
    python -m reconstruction cameras selfcalibrate --run rec/ --frames 0,40,80 --focal --out refined.json

Formats (`reconstruction.calibration_formats`): json (ours), opencv (one YAML / XML file), easymocap
(a folder with intri.yml and extri.yml), toml (anipose / caliscope), multical (calibration.json),
colmap (a folder with cameras.txt and images.txt).  The input's format is found from the path; the
output's from its name (.json is ours, .toml, .yaml / .yml / .xml), or named with --format.

``selfcalibrate`` refines the cameras of a reconstruction folder after its detect stage by bundle
adjustment over the garment's crosspoints in a few frames (`reconstruction.selfcalibration`); give
the refined file to ``run``/``detect`` with --cameras in a new folder (or triangulate with it).
"""

from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

import numpy as np

from assets.fileio import save_json

_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def add_parser(sub: "argparse._SubParsersAction") -> None:
    """Add ``cameras convert``, ``cameras calibrate`` and ``cameras selfcalibrate`` to the reconstruction
    CLI's subcommands."""
    from reconstruction.calibration_formats import FORMATS

    cameras = sub.add_parser("cameras", help="convert calibration files between tools; calibrate a rig from "
                             "ChArUco board images; refine it from the garment", description=__doc__,
                             formatter_class=argparse.RawDescriptionHelpFormatter)
    action = cameras.add_subparsers(dest="cameras_command", required=True)
    convert = action.add_parser("convert", help="read a calibration in one format and write it in another")
    convert.add_argument("input", type=Path, help="calibration file or folder (format found from the path)")
    convert.add_argument("output", type=Path, help="file or folder to write")
    convert.add_argument("--format", choices=FORMATS, help="the output's format (default: from its name)")
    convert.add_argument("--in-format", choices=FORMATS, help="the input's format (default: from the path)")
    convert.add_argument("--in-units", choices=_UNITS, default="m", help="unit of the input's translations "
                         "(anipose calibrations are often mm; default %(default)s)")
    convert.add_argument("--out-units", choices=_UNITS, default="m", help="unit of the output's translations "
                         "(default %(default)s)")
    convert.add_argument("--image-size", type=int, nargs=2, metavar=("WIDTH", "HEIGHT"),
                         help="image size for inputs that do not record it (EasyMocap without H_/W_)")
    calibrate = action.add_parser("calibrate", help="intrinsics and extrinsics of a rig from ChArUco board "
                                  "images, one folder per camera")
    calibrate.add_argument("--board", required=True, metavar="SPEC",
                           help="COLSxROWS,SQUARE_M,MARKER_M[,DICTIONARY][,legacy]: squares across and down, "
                           "square and marker side in metres, OpenCV's ArUco dictionary (default DICT_4X4_50), "
                           "'legacy' for boards made before OpenCV 4.6; e.g. 9x7,0.05,0.037,DICT_4X4_50")
    calibrate.add_argument("--images", required=True, type=Path,
                           help="folder with one sub-folder of board images per camera (the folder's name is the "
                           "camera's); images with the same file name were taken at the same instant")
    calibrate.add_argument("--out", required=True, type=Path, help="calibration to write (cameras.json, or any "
                           "format of convert)")
    calibrate.add_argument("--format", choices=FORMATS, help="the output's format (default: from its name)")
    calibrate.add_argument("--reference", help="camera the others are chained from, whose frame is the world "
                           "unless --origin-frame (default: the one sharing the most board views)")
    calibrate.add_argument("--origin-frame", metavar="FRAME",
                           help="the image (file name without suffix) whose board defines the world: lay the "
                           "board on the floor, printed side up; the origin is its outer corner next to corner 0, "
                           "Z up (default: the reference camera's frame is the world)")
    calibrate.add_argument("--min-corners", type=int, default=8, help="board corners a view needs to count "
                           "(default %(default)s)")
    calibrate.add_argument("--k3", action="store_true", help="also estimate OpenCV's sixth-order radial "
                           "coefficient k3 (for wide lenses, with board views reaching the image corners)")
    calibrate.add_argument("--no-refine", action="store_true", help="keep each camera's own intrinsics and the "
                           "chained poses, without the bundle adjustment of all of them with the board poses")

    # the adjustment's defaults are SelfCalibrationConfig's (None here): importing it (scipy) costs every CLI call
    selfcal = action.add_parser("selfcalibrate", help="refine a rig's poses (and focal lengths, k1/k2) by bundle "
                                "adjustment over the garment's crosspoints in a few frames of a reconstruction")
    selfcal.add_argument("--run", required=True, type=Path, help="reconstruction folder after its detect stage "
                         "(run.json, detections/): its cameras and detections are used")
    selfcal.add_argument("--frames", help="comma-separated frame numbers to calibrate from (default: 4 spread over "
                         "the detected frames); a few frames where the garment is seen by every camera are enough")
    selfcal.add_argument("--out", required=True, type=Path, help="refined calibration to write (cameras.json, or "
                         "any format of convert)")
    selfcal.add_argument("--format", choices=FORMATS, help="the output's format (default: from its name)")
    selfcal.add_argument("--report", type=Path, help="also write the report (per camera RMS before/after, how far "
                         "each moved) as JSON here")
    selfcal.add_argument("--focal", action="store_true", help="also refine each camera's focal length")
    selfcal.add_argument("--distortion", action="store_true", help="also refine each camera's k1 and k2")
    selfcal.add_argument("--reference", help="camera whose pose holds the gauge (default: the first)")
    selfcal.add_argument("--keep", choices=("rig", "reference"), help="world frame of the result: 'rig' (default) "
                         "fits the refined rig onto the given camera centres (similarity transform), 'reference' "
                         "keeps the reference camera's pose and its distance to the farthest camera")
    selfcal.add_argument("--loss", help="robust loss: huber, soft_l1 (default), cauchy or linear")
    selfcal.add_argument("--f-scale-px", type=float, help="the robust loss's scale, pixels (default 1)")
    selfcal.add_argument("--max-points", type=int, help="crosspoints used at most, drawn at random (default 20000)")


def _selfcalibrate(args: argparse.Namespace) -> None:
    """``cameras selfcalibrate``: the detect stage's cameras and detections of a reconstruction folder."""
    from assets.garments import load_template
    from networks.detections import Detections
    from reconstruction import pipeline
    from reconstruction.calibration_formats import write_calibration
    from reconstruction.correspondence import CrosspointMap
    from reconstruction.selfcalibration import SelfCalibrationConfig, self_calibrate_detections

    settings = pipeline.settings_of(args.run)
    cameras = pipeline.stage_cameras(args.run)
    detected = pipeline.detected_frames(args.run, cameras)
    if not detected:
        raise ValueError(f"{args.run / 'detections'}: no frame has detections from every camera")
    if args.frames:
        frames = [int(f) for f in args.frames.split(",") if f.strip()]
        if missing := sorted(set(frames) - set(detected)):
            raise ValueError(f"{args.run}: frames {missing} have no detections from every camera "
                             f"(detected: {detected})")
    else:
        spread = np.linspace(0, len(detected) - 1, min(4, len(detected))).round().astype(int)
        frames = sorted({detected[i] for i in spread})
    crosspoints = CrosspointMap.build(load_template(settings.template), settings.level_mm)
    detections = {f: [Detections.load(pipeline._detection_path(args.run, c, f)) for c in cameras] for f in frames}
    given = {"reference": args.reference, "keep": args.keep, "loss": args.loss, "f_scale_px": args.f_scale_px,
             "max_points": args.max_points}
    config = SelfCalibrationConfig(focal=args.focal, distortion=args.distortion,
                                   **{key: value for key, value in given.items() if value is not None})
    refined, report = self_calibrate_detections(crosspoints, cameras, detections, config)
    written = write_calibration(args.out, refined, args.format)
    if args.report:
        save_json(args.report, {"frames": frames, "config": asdict(config), **report.to_dict()})
    print(f"self-calibration over frames {frames}:")
    print(report.table())
    print(f"{len(refined)} cameras written to {written}")


def main(args: argparse.Namespace) -> int:
    """Run ``cameras convert``, ``cameras calibrate`` or ``cameras selfcalibrate`` parsed by `add_parser`."""
    from assets.cli import run_cli

    def action() -> None:
        from reconstruction.calibration_formats import read_calibration, write_calibration

        if args.cameras_command == "selfcalibrate":
            _selfcalibrate(args)
            return
        if args.cameras_command == "convert":
            cameras = read_calibration(args.input, args.in_format, _UNITS[args.in_units],
                                       tuple(args.image_size) if args.image_size else None)
            written = write_calibration(args.output, cameras, args.format, _UNITS[args.out_units])
            print(f"{len(cameras)} cameras from {args.input} written to {written}")
            return
        from reconstruction.charuco import CharucoBoard, RigCalibrationConfig, calibrate_rig, find_images

        board = CharucoBoard.parse(args.board)
        config = RigCalibrationConfig(min_corners=args.min_corners, k3=args.k3, refine=not args.no_refine,
                                      reference=args.reference, origin_frame=args.origin_frame)
        cameras, reports = calibrate_rig(board, find_images(args.images), config)
        written = write_calibration(args.out, cameras, args.format)
        print(f"{'camera':<16} {'views':>5} {'corners':>7} {'intrinsic RMS px':>16} {'rig RMS px':>10}  chained from")
        for r in reports:
            print(f"{r.name:<16} {r.views:>5} {r.corners:>7} {r.intrinsic_rms_px:>16.3f} {r.rig_rms_px:>10.3f}  "
                  f"{r.chained_from or '(the reference)'}")
        print(f"{len(cameras)} cameras written to {written}")

    return run_cli(action)
