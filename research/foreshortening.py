"""How oblique are the markers a network sees?  The same measure on the three sources of marker
images: the synthesizer (`networks.synth`), a rendered training dataset (`factory.dataset build`) and
a capture (`factory.dataset capture`), so training data can be matched to what a capture ring sees.

Per marker, from its four corners (TL, TR, BL, BR) in image pixels: the affine map from the printed
square that fits them best (least squares, `networks.recognizer_top1.marker_shape`); its singular
values s_min <= s_max.  `ratio` = s_min /
s_max is the foreshortening (1 frontal, 0.5 the marker seen at 60 degrees, 0 edge-on), `size` =
sqrt(s_min s_max) * edge the marker's size in pixels (the square root of its area), `rotation`
the angle of the map's rotation part (degrees, 0 upright, positive clockwise in the image: the
orientation the localizer must tell from the code to name its corners).  Markers are counted by
status: fully visible (every on-fabric point visible) and all present (also partly).

    python research/foreshortening.py --rendered .bench/rendered2 --capture .bench/cap/capture \
        --synth 60 [--synth-config '{"foreshortening": 8}'] [--scale 0.3]

--scale multiplies the capture's sizes (the Detector's --localizer-scale), so sizes compare with
what the localizer sees.  Prints a table and a `RESULT {json}` line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from assets.pattern.observation import ImageGroundTruth  # noqa: E402
from networks.recognizer_top1 import marker_affine, marker_shape, rendered_pairs  # noqa: E402

OBLIQUE = 0.6
#: markers turned by more than this from upright (degrees) count as rotated
ROTATED_DEG = 45.0


def marker_rotation(points_px: np.ndarray) -> np.ndarray:
    """(M, 5, 2) localization points -> (K,) in-plane rotation in degrees, (-180, 180], of each marker
    whose four corners are known: the angle of the rotation nearest its affine map (polar decomposition)."""
    a = marker_affine(points_px)
    return np.degrees(np.arctan2(a[:, 1, 0] - a[:, 0, 1], a[:, 0, 0] + a[:, 1, 1]))


def summary(ratio: np.ndarray, size: np.ndarray, rotation: np.ndarray | None = None) -> dict:
    if len(ratio) == 0:
        return {"markers": 0}
    q = np.percentile(ratio, [5, 25, 50])
    s = np.percentile(size, [5, 50, 95])
    turned = {} if rotation is None else {"rotated_share": float(np.mean(np.abs(rotation) > ROTATED_DEG)),
                                          "rotation_p95_deg": float(np.percentile(np.abs(rotation), 95))}
    return {"markers": int(len(ratio)), "ratio_p5": float(q[0]), "ratio_p25": float(q[1]), "ratio_median": float(q[2]),
            "oblique_share": float(np.mean(ratio < OBLIQUE)), "size_p5": float(s[0]), "size_median": float(s[1]),
            "size_p95": float(s[2]), **turned}


def measure(gts: list[ImageGroundTruth], scale: float = 1.0) -> dict:
    """Summaries of fully visible and of all present markers over ground-truth images."""
    rows = {}
    for name, least in (("fully visible", 2), ("present", 1)):
        points = [gt.points_px[gt.status >= least] for gt in gts if gt.num_markers]
        shapes = [marker_shape(p) for p in points]
        ratio = np.concatenate([r for r, _ in shapes]) if shapes else np.zeros(0)
        size = np.concatenate([s for _, s in shapes]) * scale if shapes else np.zeros(0)
        rotation = np.concatenate([marker_rotation(p) for p in points]) if points else np.zeros(0)
        rows[name] = summary(ratio, size, rotation)
    return rows


#: the splits no run trains on
HELDOUT = ("val", "test")


def capture_pairs(folder: Path) -> list[tuple[Path, Path]]:
    """(image, ground truth) paths of every view of a capture folder (``cam*/f*.png``)."""
    pairs = [(p, p.with_name(f"{p.stem}_gt.npz")) for p in sorted(folder.glob("cam*/f*.png"))]
    if not pairs:
        raise FileNotFoundError(f"{folder}: no cam*/f*.png (not a capture folder)")
    return pairs


def images_and_truth(rendered: Path | None, capture: Path | None) -> tuple[list[tuple[Path, Path]], Path]:
    """(image, ground truth) pairs and the template of a rendered dataset's held-out split or a capture."""
    if rendered is not None:
        return rendered_pairs(rendered, HELDOUT), rendered / "template.npz"
    return capture_pairs(capture), capture / "template.npz"


def synth_gts(count: int, overrides: dict) -> list[ImageGroundTruth]:
    from assets.pattern.spec import PatternSpec
    from networks.synth import PatternSynthesizer, SynthConfig

    synth = PatternSynthesizer(PatternSpec(), SynthConfig(**overrides))
    return [synth.render(i).gt for i in range(count)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rendered", type=Path, help="a factory dataset folder")
    parser.add_argument("--split", help="only this split of --rendered (default: all)")
    parser.add_argument("--capture", type=Path, help="a capture folder")
    parser.add_argument("--scale", type=float, default=1.0, help="multiply the capture's sizes (--localizer-scale)")
    parser.add_argument("--synth", type=int, default=0, help="this many synthesized 512 x 512 images")
    parser.add_argument("--synth-config", default="{}", help="SynthConfig overrides as JSON")
    args = parser.parse_args(argv)
    sources = {}
    if args.synth:
        overrides = json.loads(args.synth_config)
        name = f"synth {json.dumps(overrides)}" if overrides else "synth (defaults)"
        sources[name] = measure(synth_gts(args.synth, overrides))
    if args.rendered:
        pairs = rendered_pairs(args.rendered, None if args.split is None else (args.split,))
        sources[f"rendered {args.rendered.name}"] = measure([ImageGroundTruth.load(gt) for _, gt in pairs])
    if args.capture:
        sources[f"capture {args.capture.name} x{args.scale:g}"] = measure(
            [ImageGroundTruth.load(gt) for _, gt in capture_pairs(args.capture)], args.scale)
    if not sources:
        parser.error("give at least one of --synth, --rendered, --capture")
    print(f"| source | markers | count | ratio p5 / p25 / median | share < {OBLIQUE} | size p5 / median / p95 px "
          f"| share turned > {ROTATED_DEG:g} deg | turn p95 deg |")
    print("|---|---|---|---|---|---|---|---|")
    for source, rows in sources.items():
        for kind, r in rows.items():
            if not r["markers"]:
                print(f"| {source} | {kind} | 0 | | | | | |")
                continue
            print(f"| {source} | {kind} | {r['markers']} | {r['ratio_p5']:.2f} / {r['ratio_p25']:.2f} / "
                  f"{r['ratio_median']:.2f} | {r['oblique_share']:.0%} | {r['size_p5']:.1f} / "
                  f"{r['size_median']:.1f} / {r['size_p95']:.1f} | {r['rotated_share']:.1%} | "
                  f"{r['rotation_p95_deg']:.0f} |")
    print("RESULT " + json.dumps(sources))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
