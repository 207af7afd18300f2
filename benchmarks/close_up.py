"""Close up and far away, flat and folded (issue 46): the stored Detector on a printed square panel of
the default pattern, rendered by the factory's Blender renderer with exact ground truth, with markers
from about 12 to 200 px across, beside the issue's targets in the same run.

    python -m networks.weights fetch --out out/weights
    python benchmarks/close_up.py --out out/bench/close_up --json out/bench/close_up.json
    python benchmarks/close_up.py --sizes 25,100 --folds 0,20               # a short run
    python benchmarks/close_up.py --resolution 2048 --device cuda           # bigger images, the Detector on a GPU

The panel: a square of 23 x 23 markers (1.104 m; marker IDs 0..528, all of them among the shirt's 546
IDs that the stored ID classifier knows) cut as one seamless sewing-pattern panel
(`assets.garments`: the template, its 4 mm mesh and its print at 200 DPI, two texels per image pixel
at 200 px markers).  Folded, the panel bends along x into a sinusoid of the given amplitude (0, 10,
20 mm) and a 70 mm wavelength without stretching (the print keeps its size along the curve, as cloth
does).  The camera looks straight at it (40 degree field of view, the dataset camera's) from the
distance at which a flat marker spans the given size; where one image holds fewer than about 100
fully visible markers (large sizes), several views shifted over the panel are rendered and pooled.
Blender's studio HDRI lights it (`factory.render`, Cycles, the factory's denoising); ground truth comes from
`factory.groundtruth` with the render's depth.

Each row pools its images through `networks.evaluate_detector.evaluate_images` (the Detector with the
panel's marker tables, as reconstruction runs it; `networks.metrics` matching): precision over the
markers present, recall and ID top-1 over the fully visible ones, the centre's and the worst corner's
median error, the crosspoints' median image error and that error in crosspoint-crop pixels (the
issue's target is in the crop: x 96 crop px per marker side / the row's median marker side), the
localizer scale the Detector chose for each image (`DetectorConfig.localizer_scale`, automatic).

What runs where: Blender renders on this machine's CPU (Cycles, in a child process per fold
amplitude; 130-170 s an image at 1024 x 1024 and 16 samples on the project's 2 cores while other
work shared them); the Detector runs on --device: on those cores its crosspoint network takes about
0.5-1 s a marker (10 min for an image of 500 markers), on a GPU a fraction of a second an image.  A
run whose renders are all in --out needs neither bpy nor the mesher: render here, detect on a GPU
machine with --device cuda.  Renders, their ground truth and the panel are kept in --out and reused
by a rerun with the same settings (other sizes and amplitudes add images; another resolution or
sample count renders into its own subfolder; other panel settings are refused); an interrupted run
loses at most the image it was rendering, and its detections (the Detector runs again each time).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# only what reads renders back: a run whose renders are all there (on a GPU machine) needs neither
# bpy nor the panel's mesher (triangle), imported where the renders are made
from assets.cameras import Camera  # noqa: E402
from assets.cli import run_cli  # noqa: E402
from assets.fileio import check_settings, load_json, save_json  # noqa: E402
from assets.pattern import PatternSpec  # noqa: E402
from assets.pattern.observation import ImageGroundTruth  # noqa: E402

if TYPE_CHECKING:
    from assets.garments import Template

#: the issue's targets
TARGET_DETECTION, TARGET_ID, TARGET_POINT_PX, TARGET_CROSSPOINT_CROP_PX = 0.99, 0.995, 0.5, 0.3
ENVIRONMENT = {"type": "hdri", "file": "studio.exr", "rotation_deg": 0.0, "strength": 1.0}
CLOTH = {"roughness": 0.8, "sheen": 0.5}
WEIGHTS = Path("out/weights")


@dataclass(frozen=True)
class CloseUp:
    """What the benchmark renders.  Sizes are a flat marker's side in pixels, folds the sinusoid's
    amplitude in mm; resolution is the square image's side in pixels."""

    sizes_px: tuple[float, ...] = (12.0, 25.0, 50.0, 100.0, 200.0)
    folds_mm: tuple[float, ...] = (0.0, 10.0, 20.0)
    resolution: int = 1024
    samples: int = 16
    #: the panel's markers per side (IDs 0 .. n^2 - 1: within the stored classifier's 546 for n <= 23)
    panel_markers: int = 23
    texture_dpi: float = 200.0
    level_mm: int = 4
    wavelength_mm: float = 70.0
    fov_deg: float = 40.0
    #: views per size: enough to hold about this many fully visible markers
    min_full_markers: int = 100

    def __post_init__(self) -> None:
        problems = []
        if not self.sizes_px or not all(4 <= s <= self.resolution / 2 for s in self.sizes_px):
            problems.append(f"sizes must be marker sides in pixels in [4, {self.resolution / 2:g}] (half the "
                            f"{self.resolution} px image), got {list(self.sizes_px)}")
        if not self.folds_mm or not all(0 <= a <= self.wavelength_mm for a in self.folds_mm):
            problems.append(f"folds must be amplitudes in mm in [0, {self.wavelength_mm:g}] (the wavelength), "
                            f"got {list(self.folds_mm)}")
        if len(set(self.sizes_px)) != len(self.sizes_px) or len(set(self.folds_mm)) != len(self.folds_mm):
            problems.append("sizes and folds must not repeat")
        if self.resolution < 64 or self.samples < 1 or self.panel_markers < 1 or self.min_full_markers < 1:
            problems.append(f"resolution must be >= 64 and samples, panel_markers, min_full_markers >= 1, got "
                            f"{self.resolution}, {self.samples}, {self.panel_markers}, {self.min_full_markers}")
        if problems:
            raise ValueError("; ".join(problems))

    @property
    def panel_side(self) -> float:
        """The panel's side, metres."""
        return self.panel_markers * PatternSpec().marker_size

    @property
    def focal_px(self) -> float:
        return self.resolution / 2 / math.tan(math.radians(self.fov_deg) / 2)

    def panel_settings(self) -> dict:
        """What the panel, its print and its placement in the renders depend on (settings.json)."""
        return {key: value for key, value in asdict(self).items() if key not in ("sizes_px", "folds_mm", "resolution",
                                                                                 "samples")} | {
            "environment": ENVIRONMENT, "cloth": CLOTH}


@dataclass(frozen=True, eq=False)
class Shot:
    """One image: fold amplitude, marker size, view and its camera."""

    fold_mm: float
    size_px: float
    view: int
    camera: Camera

    @property
    def name(self) -> str:
        return f"fold{self.fold_mm:g}mm_px{self.size_px:g}_v{self.view}"


# ---- the panel ----------------------------------------------------------------------------------
def panel_template(config: CloseUp) -> Template:
    """One square panel, no seams, tiled from marker ID 0, laid out alone on its sheet at the texture DPI."""
    from assets.garments import SewingPattern, Template
    from assets.garments.layout import layout_garment

    side = config.panel_side
    pattern = SewingPattern.from_dict({"name": "panel", "panels": [{
        "name": "panel", "vertices": [[0, 0], [side, 0], [side, side], [0, side]],
        "edges": [{"name": "bottom"}, {"name": "right"}, {"name": "top"}, {"name": "left"}]}]}, "close-up panel")
    return Template(pattern, layout_garment(pattern, PatternSpec(), config.texture_dpi, sheet_width_m=side + 0.05))


def fold_curve(u: np.ndarray, amplitude: float, wavelength: float) -> tuple[np.ndarray, np.ndarray]:
    """Arc lengths u (N,) metres along the panel from its middle -> (x, depth) (N,) on the curve
    depth = amplitude sin(2 pi x / wavelength), each point u along it from x = 0 (no stretch)."""
    u = np.asarray(u, dtype=np.float64)
    if amplitude == 0:
        return u, np.zeros_like(u)
    k = 2 * np.pi / wavelength
    x = np.linspace(0.0, np.abs(u).max(), max(2, int(np.abs(u).max() / wavelength * 4000)))
    speed = np.sqrt(1 + (amplitude * k * np.cos(k * x)) ** 2)
    length = np.concatenate([[0.0], np.cumsum((speed[1:] + speed[:-1]) / 2 * np.diff(x))])
    out = np.sign(u) * np.interp(np.abs(u), length, x)
    return out, amplitude * np.sin(k * out)


def panel_positions(template: Template, config: CloseUp, fold_mm: float) -> np.ndarray:
    """(V, 3) world positions of the sewn mesh of `config.level_mm`: the panel upright in the plane
    y = 0 (pattern x -> world x, pattern y -> world z), its middle at the origin, the printed side
    towards -y, folded along x by `fold_mm`."""
    level = template.level(config.level_mm)
    xy = level.sew(level.pattern_xy) - config.panel_side / 2
    x, depth = fold_curve(xy[:, 0], fold_mm * 1e-3, config.wavelength_mm * 1e-3)
    return np.column_stack([x, -depth, xy[:, 1]])


def views(config: CloseUp, size_px: float, fold_mm: float) -> list[np.ndarray]:
    """Camera targets (x, 0, z) on the panel for `size_px`: one, or on a grid over the panel when one
    image holds fewer than `min_full_markers` fully visible markers."""
    across = config.resolution / size_px  # markers across the image
    if across >= config.panel_markers + 1:  # the whole panel in one image
        return [np.zeros(3)]
    count = math.ceil(config.min_full_markers / max(1.0, across - 1) ** 2)
    grid = math.ceil(math.sqrt(count))
    footprint = across * PatternSpec().marker_size
    width = 2 * fold_curve(np.array([config.panel_side / 2]), fold_mm * 1e-3, config.wavelength_mm * 1e-3)[0][0]
    reach = [max(0.0, (extent - footprint) / 2) * 0.9 for extent in (width, config.panel_side)]
    xs, zs = (np.linspace(-r, r, grid) if grid > 1 else np.zeros(1) for r in reach)
    return [np.array([x, 0.0, z]) for z in zs for x in xs][:count]


def shots(config: CloseUp) -> list[Shot]:
    """Every image of the run, by fold, size and view."""
    out = []
    for fold in config.folds_mm:
        for size in config.sizes_px:
            distance = config.focal_px * PatternSpec().marker_size / size
            for view, target in enumerate(views(config, size, fold)):
                camera = Camera.look_at(target - [0.0, distance, 0.0], target, focal_mm=36.0 * config.focal_px /
                                        config.resolution, width=config.resolution, height=config.resolution,
                                        name="close_up")
                out.append(Shot(fold, size, view, camera))
    return out


# ---- renders and ground truth --------------------------------------------------------------------
def prepare(config: CloseUp, out: Path, progress: bool = True) -> Template:
    """The panel's template.npz and texture.png in `out`, made once."""
    from assets.pattern.raster import write_png

    template = panel_template(config)
    if not (out / "template.npz").is_file():
        template.save(out / "template.npz", levels=(config.level_mm,))
    if not (out / "texture.png").is_file():
        write_png(out / "texture.png", template.layout.render(template.pattern, progress=progress), config.texture_dpi)
    return template


_RENDER = ("import json, sys; from dataclasses import asdict; from factory.render import render_job; "
           "print('REPORT ' + json.dumps(asdict(render_job(sys.argv[1], sys.argv[2]))))")


def render(config: CloseUp, out: Path, progress: bool = True) -> tuple[Path, list[Shot]]:
    """Render what is missing of the run's images into the folder of this resolution and sample count
    in `out` (settings.json guards the panel's settings), each with its ground truth
    (``<name>_gt.npz``) and its record (``<name>.json``: seconds a render of its job took on average,
    written last); the folder and every image of the run."""
    check_settings(out / "settings.json", config.panel_settings())
    out.mkdir(parents=True, exist_ok=True)
    save_json(out / "settings.json", config.panel_settings())
    folder, planned = out / f"{config.resolution}px_{config.samples}spp", shots(config)
    pending = [s for s in planned if not (folder / f"{s.name}.json").is_file()]
    if not pending:
        return folder, planned
    from assets.garments.markers import MarkerSurface
    from factory.plan import RenderSettings
    from factory.scenes import corner_uv, read_depth, render_job_spec, write_scene
    from factory.groundtruth import image_ground_truth

    template = prepare(config, out, progress)
    level = template.level(config.level_mm)
    surface = MarkerSurface.build(template, config.level_mm)
    # the factory's render settings (denoising on, a GPU when Blender finds one) at this size and samples
    settings = RenderSettings(resolution=(config.resolution, config.resolution), samples=config.samples)
    for fold in sorted({s.fold_mm for s in pending}):
        mine = [s for s in pending if s.fold_mm == fold]
        positions = panel_positions(template, config, fold)
        scene = folder / "scenes" / f"fold{fold:g}mm.npz"
        write_scene(scene, positions[None], level.sewn_faces, corner_uv(template, config.level_mm), np.zeros(1),
                    None, None)
        images = [{"name": s.name, "frame": 0, "camera": s.camera.to_dict(), "transform": np.eye(4).tolist(),
                   "environment": ENVIRONMENT, "cloth": CLOTH, "skin": {"rgb": [0.8, 0.6, 0.5]}, "seed": 0}
                  for s in mine]
        job = folder / "jobs" / f"fold{fold:g}mm.json"
        save_json(job, render_job_spec(settings, Path("..") / "scenes" / scene.name, Path("../..") / "texture.png",
                                       images))
        done = subprocess.run([sys.executable, "-c", _RENDER, str(job), str(folder)], cwd=ROOT, stdout=subprocess.PIPE,
                              text=True)
        reports = [line for line in done.stdout.splitlines() if line.startswith("REPORT ")]
        if done.returncode or not reports:
            raise RuntimeError(f"rendering {job} failed (status {done.returncode}):\n{done.stdout[-2000:]}")
        report = json.loads(reports[-1][len("REPORT "):])
        seconds = (report["seconds"] - report["setup_seconds"]) / max(1, len(report["rendered"]))
        for s in tqdm(mine, desc=f"ground truth fold {fold:g} mm", unit="image", disable=not progress):
            gt = image_ground_truth(surface, positions, s.camera, read_depth(folder / f"{s.name}_depth.exr"))
            gt.save(folder / f"{s.name}_gt.npz")
            save_json(folder / f"{s.name}.json", {"render_seconds": seconds if s.name in report["rendered"] else None,
                                                  "samples": config.samples, "resolution": config.resolution})
    return folder, planned


# ---- the Detector --------------------------------------------------------------------------------
def read_rgb(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    return np.ascontiguousarray(image[:, :, ::-1])


def measure(config: CloseUp, out: Path, localizer: Path, recognizer: Path, crosspoints: Path, device: str = "cpu",
            progress: bool = True) -> list[dict]:
    """Render what is missing, then run the stored Detector on every image: one row per (fold, size)."""
    for path in (localizer, recognizer, crosspoints):
        if not Path(path).is_file():
            raise FileNotFoundError(f"{path}: no such checkpoint (python -m networks.weights fetch --out {WEIGHTS})")
    folder, planned = render(config, out, progress)
    from networks.evaluate_detector import evaluate_images, load_detector
    from networks.homography import marker_side_px

    detector = load_detector(localizer, recognizer, crosspoints, out, device)  # the panel's tables: template.npz
    crop_marker_px = detector.crosspoints.crops.crosspoints.px_per_cell(detector.spec) * detector.spec.cells_per_side
    rows = []
    bar = tqdm(total=len(planned), desc="detect", unit="image", disable=not progress)
    if progress:  # each row as it is measured: a long run shows what it has
        bar.write("\n".join(TABLE_HEADER))
    for fold in config.folds_mm:
        for size in config.sizes_px:
            mine = [s for s in planned if s.fold_mm == fold and s.size_px == size]
            truths = [ImageGroundTruth.load(folder / f"{s.name}_gt.npz") for s in mine]

            def pairs():
                for s, gt in zip(mine, truths):
                    yield read_rgb(folder / f"{s.name}.png"), gt
                    bar.update()

            metrics = evaluate_images(detector, pairs())
            sides = np.concatenate([marker_side_px(gt.points_px[gt.status == 2]) for gt in truths])
            renders = [load_json(folder / f"{s.name}.json")["render_seconds"] for s in mine]
            rows.append({"fold_mm": fold, "size_px": size, "images": [s.name for s in mine],
                         "marker_px": float(np.median(sides)) if len(sides) else None, "crop_marker_px": crop_marker_px,
                         "render_seconds": [r for r in renders if r is not None], "metrics": metrics})
            if progress:
                bar.write(table_row(rows[-1]))
    bar.close()
    return rows


def summary(row: dict) -> dict:
    """The row's numbers the table shows (None where nothing was measured)."""
    m = row["metrics"]
    points = m["point_error_px"]["all"]
    corners = [points[c]["median"] for c in ("TL", "TR", "BL", "BR") if points[c]["median"] is not None]
    crosspoint = m["crosspoints"]["error_px"]["median"]
    scales = m["localizer_scale"]["per_image"]
    return {
        "fold_mm": row["fold_mm"], "size_px": row["size_px"], "marker_px": row["marker_px"], "images": len(scales),
        "full": m["markers"]["full"]["true_positive"] + m["markers"]["full"]["false_negative"],
        "precision": m["markers"]["all"]["precision"], "recall": m["markers"]["full"]["recall"],
        "id_top1": m["id_accuracy"]["full"]["accuracy"],
        "centre_px": points["centre"]["median"], "corner_px": max(corners) if corners else None,
        "crosspoint_px": crosspoint,
        "crosspoint_crop_px": None if crosspoint is None or not row["marker_px"] else
        crosspoint * row["crop_marker_px"] / row["marker_px"],
        "scales": scales, "detect_seconds": m["seconds_per_image"],
        "render_seconds": float(np.mean(row["render_seconds"])) if row["render_seconds"] else None,
    }


def _cell(value: float | None, digits: int, target: float | None = None, above: bool = True) -> str:
    """A number, '!' after it where it misses `target` (at least it when `above`, else below it)."""
    if value is None:
        return "-"
    missed = target is not None and (value < target if above else value >= target)
    return f"{value:.{digits}f}{'!' if missed else ''}"


#: the table's header, the issue's targets in its first row
TABLE_HEADER = (
    "| fold mm | marker px | measured px | images | fully visible | precision | recall | ID top-1 | centre px "
    "| worst corner px | crosspoint px | crosspoint crop px | localizer scale | detect s | render s |",
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    f"| target | | | | | >= {TARGET_DETECTION} | >= {TARGET_DETECTION} | >= {TARGET_ID} | < {TARGET_POINT_PX} "
    f"| < {TARGET_POINT_PX} | | < {TARGET_CROSSPOINT_CROP_PX} | | | |")


def table_row(row: dict) -> str:
    """One row of the table (a value missing its target ends in '!')."""
    s = summary(row)
    return (f"| {s['fold_mm']:g} | {s['size_px']:g} | {_cell(s['marker_px'], 1)} | {s['images']} | {s['full']} "
            f"| {_cell(s['precision'], 4, TARGET_DETECTION)} | {_cell(s['recall'], 4, TARGET_DETECTION)} "
            f"| {_cell(s['id_top1'], 4, TARGET_ID)} | {_cell(s['centre_px'], 3, TARGET_POINT_PX, False)} "
            f"| {_cell(s['corner_px'], 3, TARGET_POINT_PX, False)} | {_cell(s['crosspoint_px'], 3)} "
            f"| {_cell(s['crosspoint_crop_px'], 3, TARGET_CROSSPOINT_CROP_PX, False)} "
            f"| {', '.join(f'{v:.2f}' for v in s['scales'])} | {_cell(s['detect_seconds'], 2)} "
            f"| {_cell(s['render_seconds'], 1)} |")


def table(rows: list[dict]) -> str:
    """The rows as a markdown table, the targets first."""
    return "\n".join([*TABLE_HEADER, *map(table_row, rows)])


# ---- the command line ---------------------------------------------------------------------------
def _numbers(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        values = ()
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> int:
    defaults = CloseUp()
    parser = argparse.ArgumentParser(prog="python benchmarks/close_up.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("out/bench/close_up"),
                        help="folder for the panel and the renders, reused by a rerun (default %(default)s)")
    parser.add_argument("--sizes", type=_numbers, default=defaults.sizes_px, metavar="PX,...",
                        help="flat marker sides in pixels (default 12,25,50,100,200)")
    parser.add_argument("--folds", type=_numbers, default=defaults.folds_mm, metavar="MM,...",
                        help="fold amplitudes in mm, 0 = flat (default 0,10,20)")
    parser.add_argument("--resolution", type=int, default=defaults.resolution, metavar="PX",
                        help="the square image's side (default %(default)s)")
    parser.add_argument("--samples", type=int, default=defaults.samples, help="Cycles samples (default %(default)s)")
    for name in ("localizer", "recognizer", "crosspoints"):
        parser.add_argument(f"--{name}", type=Path, default=WEIGHTS / f"{name}.pt", metavar="PT",
                            help=f"the {name} checkpoint (default %(default)s)")
    parser.add_argument("--device", default="cpu", help="where the Detector runs: cpu (default) or cuda")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write every row's metrics here")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)

    def action() -> None:
        config = replace(defaults, sizes_px=args.sizes, folds_mm=args.folds, resolution=args.resolution,
                         samples=args.samples)
        start = time.perf_counter()
        rows = measure(config, args.out, args.localizer, args.recognizer, args.crosspoints, args.device,
                       progress=not args.no_progress)
        print(f"\n# close-up benchmark, {time.strftime('%Y-%m-%d')}, {platform.node()} ({platform.machine()}), "
              f"{config.resolution} x {config.resolution}, Cycles {config.samples} samples, Detector on "
              f"{args.device}, {time.perf_counter() - start:.0f} s")
        print(table(rows))
        if args.json is not None:
            save_json(args.json, {"config": asdict(config), "checkpoints": {
                "localizer": str(args.localizer), "recognizer": str(args.recognizer),
                "crosspoints": str(args.crosspoints)}, "device": args.device, "rows": rows})
            print(f"metrics written to {args.json}")
        print("RESULT " + json.dumps([summary(row) for row in rows]))

    return run_cli(action, failures=(RuntimeError,))


if __name__ == "__main__":
    sys.exit(main())
