"""`TrainConfig`: every number of one network's training run, saved with every checkpoint.

The reference gives the architectures and losses but no optimiser settings; the defaults here are
ours: Adam at lr 1e-4 with cosine decay, batches of 16 images of 512 x 512 (Marker Localizer), 256
crops of 96 x 96 (Marker Recognizer) and 64 crop pairs of 112 x 112 (Crosspoint Localizer), bf16
autocast on CUDA, augmentation on.  A config is a frozen dataclass, saved to and loaded from JSON; the
CLI (`python -m networks.train`) overrides single fields.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from assets.fileio import check_json_object, load_json, save_json
from assets.pattern.crops import MAX_CROP_JITTER_PX, CropGeometry

#: the reference's weight of the visibility BCE in the crosspoint loss (`networks.models.crosspoint_loss`)
CROSSPOINT_VISIBILITY_WEIGHT = 100.0

#: The three networks, by the name used in checkpoints, datasets and the CLIs.
TASKS = ("localizer", "recognizer", "crosspoints")

#: What the Marker Recognizer outputs (`TrainConfig.recognizer_classes`): a class per marker ID of the
#: garment or of the codebook, or a logit per code module ("modules", decoded against the codebook).
RECOGNIZER_CLASSES = ("garment", "codebook", "modules")

#: Defaults that differ between the tasks (fields left None in `TrainConfig` take these).
TASK_DEFAULTS: dict[str, dict[str, int]] = {
    "localizer": {"steps": 50_000, "batch_size": 16},
    "recognizer": {"steps": 50_000, "batch_size": 256},
    "crosspoints": {"steps": 50_000, "batch_size": 64},
}

#: the marker sides (pixels) a localizer scale may aim at (`networks.DetectorConfig.localizer_marker_px`)
MARKER_PX_RANGE = (4.0, 256.0)

#: `TrainConfig` fields that measurements removed (docs/journal/2026-11-28-crop-options-removed.md):
#: name -> the value that trains as the product now does, the only one a saved config may still carry
REMOVED_FIELDS: dict[str, object] = {
    "crosspoint_visibility_weight": CROSSPOINT_VISIBILITY_WEIGHT,
    "marker_shrink": 0.0,
    "crosspoint_margin_cells": 2,
    "crosspoint_bend": False,
    "localizer_marker_px": None,
    "recognizer_bend": False,
}


def without_removed(data: dict, removed: dict[str, object], source: str) -> dict:
    """`data` without the fields of `removed` (name -> the only value still accepted); a field of
    another value is refused, naming `source` and the field."""
    refused = [f"{name} is {data[name]!r}, an option removed from the product (only {value!r} loads)"
               for name, value in removed.items() if name in data and data[name] != value]
    if refused:
        raise ValueError(f"{source}: " + "; ".join(refused))
    return {name: value for name, value in data.items() if name not in removed}


#: the crop pixels within which the Detector moves a crosspoint onto its marker's smooth field by
#: default (`networks.DetectorConfig.smooth_crosspoints_px`), and the largest crop-pixel setting of the
#: crosspoint stage (its smoothing tolerance) that is accepted
SMOOTH_CROSSPOINTS_PX, MAX_CROP_SETTING_PX = 0.5, 8.0


#: the cells (24 per marker side) within which a marker the Detector's cut test flags keeps its own
#: points rather than its neighbours' estimate (`networks.DetectorConfig.keep_own_cells`)
KEEP_OWN_CELLS = 12.0


#: how the Detector places a marker from its detected neighbours' points (the growth of missed markers,
#: and the points of a cut marker that lie far from its own): `networks.neighbours.place_from_neighbours`
#: with Gaussian weights of this width (marker sides) around each placed point and a polynomial of this
#: degree bending the homography's residuals; a corner shared with a neighbour is that neighbour's.
#: (None, 0) is one homography over the whole neighbourhood, the placement before 2026-11-27.  Chosen
#: on the exact ground truth of 40 renders (docs/journal/2026-11-28-networks-gpu-runs.md): grown fully visible markers' centres 0.90 ->
#: 0.34 px (median), corners 0.85 -> 0.30 px; partly visible ones' centres 2.26 -> 1.48 px.
NEIGHBOUR_SIGMA_SIDES, NEIGHBOUR_DEGREE = 1.5, 2


def neighbour_fit_problem(sigma_sides: float | None, degree: int) -> str | None:
    """The problem with (`sigma_sides`, `degree`) as the neighbour placement (a width > 0 or None, and a
    degree in 0..3), or None when there is none."""
    if (sigma_sides is None or sigma_sides > 0) and isinstance(degree, int) and 0 <= degree <= 3:
        return None
    return f"the neighbour fit needs a width > 0 (or None) and a degree in 0..3, got {sigma_sides}, {degree}"


def keep_own_problem(value: float | None) -> str | None:
    """The problem with `value` as `keep_own_cells` (None: replace all five points, or a number > 0),
    or None when there is none."""
    if value is None or value > 0:
        return None
    return f"keep_own_cells must be > 0 or None, got {value}"


def crop_px_problem(name: str, value: float | None) -> str | None:
    """The problem with `value` as the crosspoint stage's crop-pixel setting `name` (None: off, or a
    number in (0, MAX_CROP_SETTING_PX]), or None when there is none."""
    if value is None or 0 < value <= MAX_CROP_SETTING_PX:
        return None
    return f"{name} must be in (0, {MAX_CROP_SETTING_PX:g}] crop pixels or None, got {value}"


def marker_px_problem(name: str, value: object) -> str | None:
    """The problem with `value` as the marker side `name` a localizer scale aims at (a number in
    MARKER_PX_RANGE), or None when it is one."""
    low, high = MARKER_PX_RANGE
    if isinstance(value, (int, float)) and not isinstance(value, bool) and low <= value <= high:
        return None
    return f"{name} must be in [{low:g}, {high:g}] pixels, got {value!r}"


@dataclass(frozen=True)
class TrainConfig:
    """One training run of the network `task` (one of `TASKS`).

    steps and batch_size default per task (`TASK_DEFAULTS`); lr is the peak learning rate, reached
    after `warmup_steps` of linear warm-up and decayed by a cosine to `lr * min_lr_ratio` at `steps`.
    synth_weight is the share of training samples drawn from the synthesizer (`networks.synth`, or
    its pre-synthesized shards) when a rendered dataset is given as well (0: rendered only; 1 or
    `--data synth`: the synthesizer alone).  image_size (pixels, square) is the side of localizer
    training images: synthesized at that size, rendered ones cut to it at random (cell-aligned; an
    image smaller than that is used whole and synthesized images take its size).
    recognizer_classes: "garment" (the reference: the Marker Recognizer classifies among the N marker
    IDs printed on the garment, `networks.data.garment_marker_ids`; N = 546 for the factory's shirt)
    or "codebook" (all `num_ids` IDs of the codebook).  The network keeps one output per codebook
    ID in both (class k is marker ID k); with "garment" the other IDs' outputs are masked off
    (`networks.train.restrict_classes`) and the checkpoint lists the classes (`recognizer_ids`).
    "modules": the network is a `networks.models.MarkerModuleReader` (one logit per code module,
    trained by a per-module BCE against the ID's grid) and the ID is decoded against the codebook
    (`networks.codes.CodeDecoder`), so it reads IDs no training garment printed; its synthesized
    crops are of any codebook ID unless a garment is given.
    val_samples caps the validation set, evaluated every `val_every` steps;
    `last.pt` is written every `checkpoint_every` steps.  pretrained: a torchvision ImageNet ResNet
    state-dict file for the backbone (None: random initialisation).  init: a checkpoint of this task
    and pattern (ours, e.g. `python -m networks.checkpoint slim`'s) whose weights a new run starts
    from, with a new optimizer and schedule (fine-tuning, or training continued across machines);
    not with pretrained.  crop_jitter_px: the training crops of the crop tasks (rendered and
    synthesized) are cut from five points moved by Gaussian noise of this
    standard deviation (pixels), as the Detector cuts them from the localizer's points; shards must
    have been written with the same (`networks.synth write --crop-jitter`); 0: the reference's exact
    crops.  `crop_geometry()` is the run's whole crop recipe, which its checkpoints carry.  view_warp (localizer, with augment): rendered training images are seen through a random
    zoom, rotation and compression (`networks.augment.ViewWarp`) with targets made anew, against
    learning the few rendered images by heart; not in the reference, which trained on many more.
    recognizer_partial (recognizer): train on crops of partial markers with a visible centre as well
    as whole ones (`assets.pattern.observation.recognizer_markers`; rendered crops cut from the
    image, shards written so: `SynthConfig.recognizer_partial`), since the Detector recognizes every
    marker the localizer finds; validation stays on whole markers.  The default, as it measured
    better: partial markers read right 0.63 -> 0.76 on renders, 0.77 -> 0.92 on a capture, whole
    ones 0.952 -> 0.963.  False: the reference's crops, whole markers only (and what
    a saved config without the field trained on).

    A saved config may still name a field that measurements removed (`REMOVED_FIELDS`) with the value
    the product now uses; `from_dict` drops it, and refuses any other value by the field's name.
    """

    task: str
    steps: int | None = None
    batch_size: int | None = None
    lr: float = 1e-4
    weight_decay: float = 0.0
    warmup_steps: int = 500
    min_lr_ratio: float = 0.01
    mixed_precision: bool = True
    image_size: int = 512
    synth_weight: float = 0.0
    augment: bool = True
    recognizer_classes: str = "garment"
    seed: int = 0
    num_workers: int = 4
    log_every: int = 50
    val_every: int = 1000
    val_samples: int = 1024
    checkpoint_every: int = 1000
    pretrained: str | None = None
    init: str | None = None
    crop_jitter_px: float = 0.0
    view_warp: bool = True
    recognizer_partial: bool = True

    def __post_init__(self) -> None:
        if self.task not in TASKS:
            raise ValueError(f"TrainConfig.task must be one of {', '.join(TASKS)}, got {self.task!r}")
        for name, value in TASK_DEFAULTS[self.task].items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)  # frozen: fill the task's default once
        problems = []
        for name in ("steps", "batch_size", "image_size", "log_every", "val_every", "val_samples",
                     "checkpoint_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                problems.append(f"{name} must be an integer >= 1, got {value!r}")
        for name in ("warmup_steps", "num_workers", "seed"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                problems.append(f"{name} must be an integer >= 0, got {value!r}")
        if not (isinstance(self.lr, (int, float)) and self.lr > 0):
            problems.append(f"lr must be > 0, got {self.lr!r}")
        if not (isinstance(self.weight_decay, (int, float)) and self.weight_decay >= 0):
            problems.append(f"weight_decay must be >= 0, got {self.weight_decay!r}")
        if not (isinstance(self.min_lr_ratio, (int, float)) and 0 <= self.min_lr_ratio <= 1):
            problems.append(f"min_lr_ratio must be in [0, 1], got {self.min_lr_ratio!r}")
        if not (isinstance(self.crop_jitter_px, (int, float)) and 0 <= self.crop_jitter_px <= MAX_CROP_JITTER_PX):
            problems.append(f"crop_jitter_px must be in [0, {MAX_CROP_JITTER_PX:g}] pixels, got {self.crop_jitter_px!r}")
        if not (isinstance(self.synth_weight, (int, float)) and 0 <= self.synth_weight <= 1):
            problems.append(f"synth_weight must be in [0, 1], got {self.synth_weight!r}")
        if self.recognizer_classes not in RECOGNIZER_CLASSES:
            problems.append(f"recognizer_classes must be one of {', '.join(RECOGNIZER_CLASSES)}, "
                            f"got {self.recognizer_classes!r}")
        if self.task == "localizer" and self.image_size % 8:
            problems.append(f"image_size must be a multiple of 8 (the localizer's cell), got {self.image_size}")
        for name in ("pretrained", "init"):
            if getattr(self, name) is not None and not isinstance(getattr(self, name), str):
                problems.append(f"{name} must be a path string or null, got {getattr(self, name)!r}")
        if self.pretrained is not None and self.init is not None:
            problems.append("give pretrained (ImageNet backbone weights) or init (a checkpoint to start from), not both")
        if problems:
            raise ValueError("invalid TrainConfig: " + "; ".join(problems))

    def crop_geometry(self) -> CropGeometry:
        """How this run's crops are cut: the reference's crops from points jittered by crop_jitter_px
        (the localizer's run cuts none: exact)."""
        return CropGeometry(jitter_px=float(self.crop_jitter_px) if self.task != "localizer" else 0.0)

    def replace(self, **overrides: object) -> "TrainConfig":
        """A copy with `overrides` (field name -> value); None values are ignored."""
        unknown = sorted(set(overrides) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise ValueError(f"TrainConfig has no field(s) {', '.join(unknown)}")
        return dataclasses.replace(self, **{k: v for k, v in overrides.items() if v is not None})

    def to_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: object, source: str = "TrainConfig") -> "TrainConfig":
        """Build from a dict (as `to_dict` writes); unknown fields, bad values and removed fields of
        another value than `REMOVED_FIELDS` name `source`."""
        check_json_object(data, [f.name for f in dataclasses.fields(cls)] + list(REMOVED_FIELDS), source)
        if "task" not in data:
            raise ValueError(f"{source}: missing field 'task' (one of {', '.join(TASKS)})")
        data = without_removed(data, REMOVED_FIELDS, source)
        data = {"recognizer_partial": False, **data}  # configs from before the field: whole markers only
        try:
            return cls(**data)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {exc}") from exc

    def save(self, path: str | Path) -> None:
        save_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "TrainConfig":
        return cls.from_dict(load_json(path), source=str(path))
