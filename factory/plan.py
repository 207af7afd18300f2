"""What a training dataset is: its settings (`RenderSettings`, `DatasetConfig`), its plan (splits,
per-image variations, environments, the fixed camera) and the simulations it asks for.

Every random choice comes from a generator seeded by (seed, motion, frame, variation), so any image
can be remade alone.  Frames are split into train, validation and test at 22:2:1 **by simulation
frame**: the variations of one frame never straddle splits.  The folder layout and the CLI:
`factory.dataset`; the build: `factory.build`.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from assets.body import load_body
from assets.cameras import Camera
from assets.fileio import copy_file, load_npz
from factory.dressing import DressingParams
from factory.simulate import SimulationConfig, read_meta

#: the reference's train : validation : test ratio, by simulation frame
SPLIT_RATIO = (22, 2, 1)
SPLITS = ("train", "val", "test")
#: the two sky worlds added to Blender's eight HDRIs (10 environments)
SKY_WORLDS = 2


@dataclass(frozen=True)
class RenderSettings:
    resolution: tuple[int, int] = (512, 512)  # width, height
    engine: str = "CYCLES"
    samples: int = 64
    denoise: bool = True
    device: str = "auto"
    #: pattern texture resolution; 100 DPI is 7.9 texels per 2 mm cell
    texture_dpi: float = 100.0


@dataclass(frozen=True)
class DatasetConfig:
    garment: str
    motions: tuple[str, ...]
    body: str = "default"
    #: the body's shape values (`BodyModel.shape_names`); None: each motion's own or the body's default
    betas: tuple[float, ...] | None = None
    #: frames per motion, `frame_step` simulation frames (1/120 s) apart after the dressing transition
    frames: int = 8
    frame_step: int = 12
    #: explicit simulation frame indices instead of `frames` x `frame_step` (tests, hand-picked frames)
    frame_list: tuple[int, ...] | None = None
    variations: int = 5
    seed: int = 0
    #: the simulation's template level (mm) and motion speed multiplier (`factory.simulate`'s --level, --speed)
    level_mm: int = DressingParams.level_mm
    motion_speed: float = 1.0
    render: RenderSettings = field(default_factory=RenderSettings)
    #: largest random tilt (degrees) and translation (m) of garment and body per variation
    max_tilt_deg: float = 10.0
    max_shift: float = 0.05
    #: the camera's horizontal field of view (degrees) and how much of the frame the garment fills
    fov_deg: float = 40.0
    fill: float = 0.85


# ---- plans -------------------------------------------------------------------------------------

def keyed_rng(*keys: object) -> np.random.Generator:
    """A generator seeded by `keys` (their text): the same keys give the same choices anywhere."""
    digest = hashlib.sha256(json.dumps([str(k) for k in keys]).encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def split_of_frames(units: list[tuple[str, int]], seed: int, ratio: tuple[int, int, int] = SPLIT_RATIO) -> dict:
    """(motion, frame) units -> split name, at `ratio` (train : val : test) over a seeded shuffle;
    with three or more units, validation and test get at least one each."""
    order = keyed_rng("split", seed).permutation(len(units))
    n = len(units)
    total = sum(ratio)
    n_test = int(round(n * ratio[2] / total))
    n_val = int(round(n * ratio[1] / total))
    if n >= 3:
        n_test, n_val = max(1, n_test), max(1, n_val)
    names = ["test"] * n_test + ["val"] * n_val + ["train"] * (n - n_test - n_val)
    return {units[i]: names[k] for k, i in enumerate(order)}


def environments(bundled: list[str]) -> list[dict]:
    """The 10 environments: Blender's bundled HDRIs (by file name) and two skies."""
    return [{"type": "hdri", "file": name} for name in bundled] + [{"type": "sky"} for _ in range(SKY_WORLDS)]


def variation(config: DatasetConfig, motion: str, frame: int, v: int, centre: np.ndarray, envs: list[dict]) -> dict:
    """The random choices of one image: garment transform, environment, materials, seed."""
    rng = keyed_rng(config.seed, motion, frame, v)
    tilt = np.clip(rng.normal(0.0, config.max_tilt_deg / 2, 2), -config.max_tilt_deg, config.max_tilt_deg)
    rotation = Rotation.from_euler("zxy", [rng.uniform(0.0, 360.0), tilt[0], tilt[1]], degrees=True).as_matrix()
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = rotation @ -centre + rng.uniform(-config.max_shift, config.max_shift, 3)
    env = dict(envs[int(rng.integers(len(envs)))])
    if env["type"] == "hdri":
        env.update(rotation_deg=float(rng.uniform(0.0, 360.0)), strength=float(rng.uniform(0.7, 1.3)))
    else:
        env.update(sun_elevation_deg=float(rng.uniform(15.0, 60.0)), sun_rotation_deg=float(rng.uniform(0.0, 360.0)),
                   strength=float(rng.uniform(0.03, 0.1)))  # brighter overexposes
    skin = np.array([[0.85, 0.64, 0.52], [0.62, 0.43, 0.32], [0.40, 0.26, 0.18], [0.93, 0.76, 0.66]])
    return {
        "transform": transform.tolist(), "environment": env,
        "cloth": {"roughness": float(rng.uniform(0.6, 0.95)), "sheen": float(rng.uniform(0.2, 0.8))},
        "skin": {"rgb": (skin[rng.integers(len(skin))] * rng.uniform(0.9, 1.1)).clip(0, 1).tolist()},
        "seed": int(rng.integers(2**31 - 1)),
    }


def fixed_camera(radius: float, settings: RenderSettings, fov_deg: float, fill: float) -> Camera:
    """The dataset's camera, in front of the origin (-Y, looking +Y), far enough that a sphere of
    `radius` around the origin fills `fill` of the narrower image side."""
    width, height = settings.resolution
    half = np.radians(fov_deg) / 2
    narrow = min(1.0, height / width)
    distance = radius / np.sin(np.arctan(np.tan(half) * narrow) * fill)
    sensor = 36.0
    focal = sensor / (2 * np.tan(half))
    return Camera.look_at((0.0, -distance, 0.0), (0.0, 0.0, 0.0), focal_mm=focal, sensor_mm=sensor,
                          width=width, height=height, name="fixed")


# ---- simulations -------------------------------------------------------------------------------

def input_record(digests: dict[str, str]) -> dict[str, str]:
    """The SHA-256 of a stage's input files ({what: digest}, `factory.simulate.input_digests`) as
    settings of its record, one per file ("inputs.<what>"), so a refusal names the file that changed."""
    return {f"inputs.{what}": digest for what, digest in digests.items()}


def simulation_config(garment: str, motion: str, body: str = "default", frames: int = 1, seed: int = 0,
                      level_mm: int = DressingParams.level_mm, motion_speed: float = 1.0,
                      betas: tuple[float, ...] | None = None) -> SimulationConfig:
    """The simulation the factory makes of `motion` (`factory.simulate`'s defaults otherwise)."""
    return SimulationConfig(garment=garment, motion=motion, body=body, frames=frames, betas=betas, seed=seed,
                            motion_speed=motion_speed, dressing=replace(DressingParams(), level_mm=level_mm))


def check_betas(betas: str | tuple[float, ...] | None, body: str, option: str = "betas") -> tuple[float, ...] | None:
    """`betas` (numbers, or an option's comma-separated text) as the shape values of `body`: finite
    numbers, one per `shape_names` entry, within the body's range; None stays None (the motion's or the
    body's own shape).  A ValueError names `option` and the body's shape values."""
    if betas is None:
        return None
    model = load_body(body)
    expected = f"{model.num_betas} comma-separated numbers ({', '.join(model.shape_names)}) for body {body!r}"
    try:
        values = tuple(float(v) for v in (betas.split(",") if isinstance(betas, str) else betas))
    except (TypeError, ValueError):
        raise ValueError(f"{option}: expected {expected}, got {betas!r}") from None
    if len(values) != model.num_betas or not np.isfinite(values).all():
        raise ValueError(f"{option}: expected {expected}, got {betas!r}")
    try:
        model.shape_coefficients(np.asarray(values))
    except ValueError as exc:  # outside a shape grid's range
        raise ValueError(f"{option}: {exc}") from None
    return values


def reuse_simulation(source: str | Path, target: Path, config: SimulationConfig) -> None:
    """Copy a finished simulation folder (``sequence.npz``, ``dressed.npz``) to `target`, where
    `factory.simulate` takes it up (and continues it when it has fewer frames than needed).  A folder
    holding another simulation than `config`'s (which would silently be simulated again) is refused,
    naming the options that differ."""
    source = Path(source)
    if not (source / "sequence.npz").is_file():
        raise ValueError(f"{source}: no sequence.npz (not a finished simulation folder)")
    meta = read_meta(source / "sequence.npz", load_npz(source / "sequence.npz", only=("meta",)))
    if meta.get("key") != config.key():
        differ = config.differences(meta.get("config", {})) or ["the simulator's version"]
        raise ValueError(f"{source / 'sequence.npz'}: another simulation than this one's (recorded there, not here: "
                         f"{'; '.join(differ)}); give the options it was made with (--garment, --motion, --body, "
                         "--betas, --seed, --level, --speed) or leave out --reuse-simulation")
    for name in ("sequence.npz", "dressed.npz"):
        if (source / name).is_file() and not (target / name).exists():
            copy_file(source / name, target / name)
