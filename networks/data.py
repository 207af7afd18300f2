"""Training data of the three networks as torch Datasets: rendered (factory folders), synthesized (on
the fly or pre-synthesized shards, `networks.shards`), mixed.

Items are dicts of torch tensors without a batch dimension, so the default collate stacks them:

  localizer:   {"image": uint8 (3, H, W), "cells": float32 (H/8, W/8, 11)}
  recognizer:  {"crop": uint8 (3, 96, 96), "marker_id": int64 ()}
  crosspoints: {"crop": uint8 (3, 112, 112), "reference": uint8 (3, 112, 112),
                "xy": float32 (25, 25, 2) crop pixels, NaN off the fabric, "visible": bool (25, 25)
                seen in the image and inside the crop (every visible xy is in [0, 112])}

`cells`, crops, `xy` and `visible` are exactly `assets.pattern.observation`'s targets; `reference` is the
marker's canonical crop (`reference_textures` of its codebook row).  Every random choice (which
synthetic sample, which crop, augmentation) comes from a generator seeded by (seed, epoch, index), so
an item is reproducible and DataLoader workers need no seeding (no `worker_init_fn`); `set_epoch(e)`
before each epoch gives new augmentations (and new synthetic samples) while staying reproducible.
Do not call `cv2.setNumThreads` inside a forked worker: when the parent has used OpenCV's thread pool,
that call deadlocks the worker (measured here: every time).

A factory dataset folder (`factory.dataset`) holds manifest.jsonl (one JSON object per finished image:
name, split, image, samples, ...), splits.json, images/<name>.png, samples/<name>.npz (cells,
recognizer_crops/_ids, crosspoint_crops/_ids/_xy/_visible) and template.npz, whose layout_json
carries the garment's pattern spec (the codebook of the crosspoint references) and its panels, whose
marker IDs (`garment_marker_ids`) are the classes of the reference's Marker Recognizer.

A shard folder (`networks.shards` writes it, `ShardDataset` reads it) holds pre-synthesized items of
one task: shards.json (format, task, pattern spec, codebook hash, synthesizer config, marker IDs) and
part_NNNNN/ folders of .npy arrays (`SHARD_ARRAYS`), memory-mapped on read, so a worker costs little
more than the augmentation.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from dataclasses import fields
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np
import torch
from torch.utils.data import ConcatDataset, Dataset
from tqdm import tqdm

from assets.fileio import load_json, load_npz, save_npz
from assets.geometry import apply_homography
from assets.pattern.codebook import generate_codebook
from assets.pattern.crops import CROSSPOINT_CROP, MAX_CROP_JITTER_PX, RECOGNIZER_CROP, CropGeometry, reference_textures, unwarp
from assets.pattern.observation import (ImageGroundTruth, completed_points, crosspoint_centre_markers, crosspoint_crops,
                                        crosspoint_markers, localizer_targets, marker_cells, recognizer_crops,
                                        recognizer_markers, training_samples)
from assets.pattern.spec import PatternSpec
from networks.augment import Augment, ViewWarp, warp_image
from networks.checkpoint import codebook_hash
from networks.config import TASKS
from networks.decoded import DecodedArrays
from networks.models import CELL
from networks.synth import PatternSynthesizer, SynthConfig

SPLITS = ("train", "val", "test")
#: the arrays of samples/<name>.npz each crop task reads
_CROP_KEYS = {
    "recognizer": ("recognizer_crops", "recognizer_ids"),
    "crosspoints": ("crosspoint_crops", "crosspoint_ids", "crosspoint_xy", "crosspoint_visible"),
}
#: the prefix of the ground-truth arrays a crosspoint image decoded ahead keeps (`RenderedDataset._read`)
_GT = "gt."
#: synthetic samples tried for one crop item before giving up (a sample may show no usable marker)
_ATTEMPTS = 32
#: the stream of a synthetic sample's crop jitter (`synth_crops`), apart from the synthesizer's own
_JITTER = 7
#: the stream of a rendered localizer item's view warp (`ViewWarp`), apart from its crop's and augmentation's
_VIEW = 8
#: shard folders: the format name in shards.json, and the arrays of a part per task (first axis: item)
SHARD_FORMAT = "clothcapture-synth-shards"
SHARD_META = "shards.json"
SHARD_ARRAYS = {
    "localizer": ("image", "cells"),
    "recognizer": ("crop", "marker_id"),
    "crosspoints": ("crop", "marker_id", "xy", "visible"),
}


def _template_path(source: str | Path) -> Path:
    """template.npz itself, or the one in a factory dataset folder."""
    source = Path(source)
    return source / "template.npz" if source.is_dir() else source


def _layout(source: str | Path) -> dict:
    path = _template_path(source)
    if not path.is_file():
        raise ValueError(f"{source}: no template.npz (the garment template holding the pattern spec); "
                         "pass spec= explicitly")
    text = load_npz(path, only=("layout_json",))["layout_json"]
    try:
        layout = json.loads(text.tobytes())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: layout_json is not valid JSON ({exc})") from exc
    if not isinstance(layout, dict) or "spec" not in layout:
        raise ValueError(f"{path}: layout_json has no 'spec'")
    return layout


def dataset_spec(root: str | Path) -> PatternSpec:
    """The pattern spec of a factory dataset folder (or of a template.npz), from template.npz's
    layout_json (read without assets.garments, so without its mesh dependencies)."""
    return PatternSpec.from_dict(_layout(root)["spec"], source=f"{_template_path(root)}:layout_json.spec")


def garment_marker_ids(root: str | Path) -> np.ndarray:
    """(N,) int64 sorted marker IDs printed on the garment of a factory dataset folder (or of a
    template.npz): every panel's first_id + 0 .. rows * cols - 1.  N is the reference's number of
    Marker Recognizer classes."""
    path = _template_path(root)
    layout = _layout(root)
    try:
        ids = [int(p["first_id"]) + np.arange(int(p["spec"]["rows"]) * int(p["spec"]["cols"]))
               for p in layout["panels"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: layout_json.panels lacks first_id or spec rows / cols ({exc!r})") from exc
    if not ids:
        raise ValueError(f"{path}: layout_json has no panels, so no marker IDs")
    ids = np.unique(np.concatenate(ids)).astype(np.int64)
    num_ids = int(layout["spec"].get("num_ids", PatternSpec().num_ids))
    if ids[0] < 0 or ids[-1] >= num_ids:
        raise ValueError(f"{path}: panel marker IDs {ids[0]}..{ids[-1]} are outside the codebook of {num_ids}")
    return ids


class _Items:
    """Shared item building: augmentation, reference textures, tensors."""

    task: str
    seed: int
    epoch: int = 0
    augment: Augment | None
    spec: PatternSpec | None
    codebook: np.ndarray | None
    _references: dict[int, np.ndarray]

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def _rng(self, index: int, part: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, self.epoch, int(index), part])

    def _augmented(self, image: np.ndarray, index: int) -> np.ndarray:
        return image if self.augment is None else self.augment(image, self._rng(index, 1))

    def _reference(self, marker_id: int) -> np.ndarray:
        cache = self._references
        if marker_id not in cache:
            if not 0 <= marker_id < len(self.codebook):
                raise ValueError(f"marker ID {marker_id} is outside the codebook of {len(self.codebook)} IDs")
            cache[marker_id] = reference_textures(self.spec, self.codebook[marker_id][None],
                                                  CROSSPOINT_CROP)[0]
        return cache[marker_id]

    def _item(self, index: int, image=None, cells=None, crop=None, marker_id=None, xy=None, visible=None) -> dict:
        """The task's item from numpy arrays: images and crops (H, W, 3) uint8 (augmented here)."""
        if self.task == "localizer":
            return {"image": _chw(self._augmented(image, index)),
                    "cells": torch.from_numpy(np.array(cells, np.float32))}  # a copy: never a cached array
        item = {"crop": _chw(self._augmented(crop, index))}
        if self.task == "recognizer":
            return {**item, "marker_id": torch.tensor(int(marker_id), dtype=torch.int64)}
        return {**item, "reference": _chw(self._reference(int(marker_id))),
                "xy": torch.from_numpy(np.array(xy, np.float32)),
                "visible": torch.from_numpy(np.array(visible, bool))}


class RenderedDataset(_Items, Dataset):
    """The items of one split of a factory dataset folder.

    root: the folder; split: "train", "val" or "test"; task: one of `networks.config.TASKS`.  A crop
    task indexes every crop of every image of the split (the index is built once, reading only the
    ID arrays).  spec: the pattern spec for the crosspoint references (default: the folder's
    template.npz).  cache_images: images whose decoded files (the localizer's PNG and cells, a crop
    task's samples/<name>.npz) are kept per worker (crops of one image are read together; a sampler
    that keeps an image's crops close together profits most).
    crop_px: localizer items are random crops of min(crop_px, side) pixels per side (rounded down to
    whole 8 px cells and placed on the cell grid, so the cell targets stay exact; seeded per
    (seed, epoch, index)); None: whole images.  view_warp (localizer): an item of that size is, at
    the warp's probability, the image seen through a random `ViewWarp` instead of a crop, its cell
    targets made anew from the image's ground-truth points (gt/<name>.npz) moved by the same
    homography; a marker is present when its centre was visible and lands inside the item.
    crop_jitter_px (crop tasks): each item's crop is cut anew from the image, from its marker's five
    true points moved by Gaussian noise of this standard deviation in pixels (seeded per (seed,
    epoch, index)), as the Detector cuts crops from the localizer's points; crosspoint targets follow
    the moved crop (`ImageGroundTruth.jittered`).  The markers are those of the stored crops, picked
    on the true points (`crosspoint_markers`' crop-sanity test); a jittered crosspoint crop that fails
    that test (the Detector would not cut it) is cut from the true points.  0: the stored exact crops.
    partial_markers (recognizer): the items are the markers of `recognizer_markers(partial=True)`
    (whole markers and partial ones with a visible centre), their crops cut from the image
    (gt/<name>.npz's points, jittered by crop_jitter_px), not the stored crops of whole markers.
    decode_ahead: what an item reads of its image from disk is decoded once for every image of the
    split, when the dataset is made, into a memory-mapped file the workers share (`networks.decoded`;
    a split too large for its limit is read per item as without): the localizer's image and cells;
    for crops cut anew, the image and (crosspoints) its markers' ground truth; else the stored crops
    of samples/<name>.npz."""

    def __init__(self, root: str | Path, split: str, task: str, augment: Augment | None = None,
                 spec: PatternSpec | None = None, seed: int = 0, cache_images: int = 32,
                 crop_px: int | None = None, crop_jitter_px: float = 0.0, view_warp: ViewWarp | None = None,
                 partial_markers: bool = False, decode_ahead: bool = False):
        if task not in TASKS:
            raise ValueError(f"task must be one of {', '.join(TASKS)}, got {task!r}")
        if split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
        self.root, self.split, self.task, self.augment, self.seed = Path(root), split, task, augment, seed
        self.cache_images = max(1, int(cache_images))
        if crop_px is not None and crop_px < CELL:
            raise ValueError(f"crop_px must be >= {CELL} (one localizer cell), got {crop_px}")
        self.crop_px = crop_px
        if not 0 <= crop_jitter_px <= MAX_CROP_JITTER_PX or (crop_jitter_px > 0 and task == "localizer"):
            raise ValueError(f"crop_jitter_px must be in [0, {MAX_CROP_JITTER_PX:g}] and only for the crop tasks, got {crop_jitter_px} "
                             f"for the {task}")
        self.crop_jitter_px = float(crop_jitter_px)
        if view_warp is not None and task != "localizer":
            raise ValueError(f"view_warp is for the localizer's images, not the {task} task's crops")
        self.view_warp = view_warp
        if partial_markers and task != "recognizer":
            raise ValueError(f"partial_markers is for the recognizer's crops, not the {task} task's")
        self.partial_markers = bool(partial_markers)
        self._decoded: DecodedArrays | None = None
        self._references = {}
        self._cache: OrderedDict[int, dict[str, np.ndarray]] = OrderedDict()
        self.entries = [e for e in _manifest(self.root) if e["split"] == split]
        if not self.entries:
            raise ValueError(f"{self.root}: no images in split {split!r}")
        needed = ["samples"] + (["image"] if task == "localizer" or self._cut_anew else []) + \
            (["gt"] if view_warp or self._cut_anew else [])
        missing = [e.get(k, f"{e.get('name')} has no {k!r} entry") for e in self.entries for k in needed
                   if k not in e or not (self.root / e[k]).is_file()]
        if missing:
            raise ValueError(f"{self.root}: {len(missing)} file(s) of the manifest are missing, e.g. {missing[:3]}")
        self.spec = self.codebook = None
        if task == "crosspoints" or self._cut_anew:  # references, or crops cut anew
            self.spec = spec if spec is not None else dataset_spec(self.root)
        # what per-image work the items need (completed points, the markers' picks) is done here, once,
        # before DataLoader workers fork: done per worker and image, it starved the GPU (a mixed
        # batch draws its rendered items from random images, so the workers' caches rarely hit)
        self._sources: list[dict[str, np.ndarray]] = []
        quiet = len(self.entries) < (50 if self._cut_anew or view_warp else 1000)
        entries = tqdm(range(len(self.entries)), desc=f"index {split} {task}", disable=quiet)
        if task == "localizer":
            self._index = np.stack([np.arange(len(self.entries)), np.zeros(len(self.entries), np.int64)], axis=1)
            self._markers = {i: self._warp_markers(i) for i in entries} if view_warp else {}
        else:
            key = _CROP_KEYS[task][1]
            if self._cut_anew:
                self._sources = [self._marker_source(i) for i in entries]
                counts = [len(source[key]) for source in self._sources]
            else:
                counts = [len(load_npz(self.root / self.entries[i]["samples"], only=(key,))[key]) for i in entries]
            image = np.repeat(np.arange(len(self.entries)), counts)
            crop = np.arange(len(image)) - np.repeat(np.cumsum(counts) - counts, counts)
            self._index = np.stack([image, crop], axis=1).astype(np.int64)
        if task == "crosspoints":
            self.codebook = generate_codebook(self.spec)  # before DataLoader workers fork, so they share it
        if decode_ahead:
            self._decoded = DecodedArrays.write((self._read(i) for i in range(len(self.entries))),
                                                len(self.entries), desc=f"decode {split} {task} images ahead")

    def __len__(self) -> int:
        return len(self._index)

    @property
    def decoded_bytes(self) -> int:
        """Size of the file of images decoded ahead (`decode_ahead`); 0 when they are read per image."""
        return 0 if self._decoded is None else self._decoded.nbytes

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} items")
        image_index, crop = (int(v) for v in self._index[index])
        arrays = self._arrays(image_index)
        if self.task == "localizer":
            image, cells = arrays["image"], arrays["cells"]
            h, w = image.shape[:2]
            width, height = self.crop_size((w, h))
            view = None if self.view_warp is None else self.view_warp.homography(self._rng(index, _VIEW), (w, h),
                                                                                 (width, height))
            if view is not None:  # the targets: the source's points through the view
                return self._item(index, image=warp_image(image, view, (width, height)),
                                  cells=self._warped_cells(image_index, view, (width, height)))
            if self.crop_px is not None:
                rng = self._rng(index, 3)
                i0, j0 = (int(rng.integers(0, n + 1)) for n in ((h - height) // CELL, (w - width) // CELL))
                image = image[i0 * CELL:i0 * CELL + height, j0 * CELL:j0 * CELL + width]
                cells = cells[i0:i0 + height // CELL, j0:j0 + width // CELL]
            return self._item(index, image=image, cells=cells)
        if self.task == "recognizer":
            if self._cut_anew:
                image, points = arrays["image"], arrays["points_px"][crop]
                if self.crop_jitter_px > 0:
                    points = points + self._rng(index, _JITTER).normal(0.0, self.crop_jitter_px, (5, 2))
                cut = unwarp(image, self.spec, RECOGNIZER_CROP, points)
                return self._item(index, crop=cut, marker_id=arrays["recognizer_ids"][crop])
            return self._item(index, crop=arrays["recognizer_crops"][crop], marker_id=arrays["recognizer_ids"][crop])
        if self._cut_anew:
            image, one = arrays["image"], arrays["gt"].select(np.array([crop]))
            made = None
            if self.crop_jitter_px > 0:
                made = crosspoint_crops(image, one.jittered(self.crop_jitter_px, self._rng(index, _JITTER)),
                                        self.spec, CROSSPOINT_CROP)
            if made is None or not len(made[0]):  # unjittered, or the jittered fit fails the sanity test
                made = crosspoint_crops(image, one, self.spec, CROSSPOINT_CROP)
            cut, marker_id, xy, visible = (a[0] for a in made)
            return self._item(index, crop=cut, marker_id=marker_id, xy=xy, visible=visible)
        return self._item(index, crop=arrays["crosspoint_crops"][crop], marker_id=arrays["crosspoint_ids"][crop],
                          xy=arrays["crosspoint_xy"][crop], visible=arrays["crosspoint_visible"][crop])

    def crop_size(self, image_size: tuple[int, int]) -> tuple[int, int]:
        """(width, height) of the localizer items cut from an image of `image_size` (width, height)."""
        if self.crop_px is None:
            return tuple(image_size)
        return tuple(min(self.crop_px, side) // CELL * CELL for side in image_size)

    def _arrays(self, image_index: int) -> dict[str, np.ndarray]:
        """One image's arrays as its items use them (`_read`'s, from the file decoded ahead when there
        is one), kept in a small per-worker cache: the localizer's image and cells, a crop task's
        stored crops, or what crops cut anew are cut from (`_marker_source`
        with the image, and for crosspoints its markers' `ImageGroundTruth` as "gt")."""
        if image_index in self._cache:
            self._cache.move_to_end(image_index)
            return self._cache[image_index]
        arrays = self._read(image_index) if self._decoded is None else self._decoded[image_index]
        if self._cut_anew and self.task != "localizer":
            source = self._sources[image_index]
            if self.task == "crosspoints":
                gt = {name[len(_GT):]: array for name, array in arrays.items() if name.startswith(_GT)}
                size = {"width": int(gt.pop("width")), "height": int(gt.pop("height"))}
                return self._keep(image_index, {"image": arrays["image"], "gt": ImageGroundTruth(**size, **gt),
                                                **source})
            arrays = {"image": arrays["image"], **source}
        return self._keep(image_index, arrays)

    def _read(self, image_index: int) -> dict[str, np.ndarray]:
        """What this task's items need of one image from its files, decoded (arrays only: what
        decode_ahead keeps): the localizer's image and cells; for crops cut anew the image and, for
        crosspoints, the ground truth of its markers (`_marker_source`'s pick) as "gt.<field>"
        arrays; else the stored crops (and targets) of samples/<name>.npz, checked."""
        entry = self.entries[image_index]
        if self.task == "localizer":
            return self._read_localizer(image_index)
        if self._cut_anew:
            image = _read_png(self.root / entry["image"])
            if self.task == "recognizer":
                return {"image": image}
            gt = ImageGroundTruth.load(self.root / entry["gt"]).select(self._sources[image_index]["pick"])
            return {"image": image, **{_GT + f.name: np.asarray(getattr(gt, f.name)) for f in fields(gt)}}
        path = self.root / entry["samples"]
        arrays = load_npz(path, only=_CROP_KEYS[self.task])
        count = len(arrays[_CROP_KEYS[self.task][1]])
        size = (RECOGNIZER_CROP if self.task == "recognizer" else CROSSPOINT_CROP).size_px
        expected = {_CROP_KEYS[self.task][0]: ((count, size, size, 3), np.uint8)}
        if self.task == "crosspoints":
            k = self.spec.crosspoints_per_side
            expected.update(crosspoint_xy=((count, k, k, 2), np.float32), crosspoint_visible=((count, k, k), np.bool_))
        problems = [f"{name} is {arrays[name].shape} {arrays[name].dtype}, expected {shape} {np.dtype(dtype).name}"
                    for name, (shape, dtype) in expected.items()
                    if arrays[name].shape != shape or arrays[name].dtype != dtype]
        if problems:
            raise ValueError(f"{path}: " + "; ".join(problems))
        return arrays

    @property
    def _cut_anew(self) -> bool:
        """Crops are cut from the image per item (crop jitter, partial markers), not read stored."""
        return self.crop_jitter_px > 0 or self.partial_markers

    def _marker_source(self, image_index: int) -> dict[str, np.ndarray]:
        """What an image's crops cut anew are cut from, but its pixels: the recognizer's five points per
        crop (`recognizer_markers`; with partial_markers, `completed_points`) or the crosspoint network's
        markers (`pick`, indices into gt/<name>.npz: `crosspoint_markers`), with their IDs.  Without
        partial_markers they are checked against the samples' stored crops: the markers of those."""
        entry = self.entries[image_index]
        gt = ImageGroundTruth.load(self.root / entry["gt"])
        key = _CROP_KEYS[self.task][1]
        if self.partial_markers:  # the stored crops hold whole markers only: nothing to check against
            completed = completed_points(gt)
            pick = recognizer_markers(gt, self.spec, True, completed)
            return {"points_px": completed[pick].astype(np.float64), key: gt.marker_id[pick]}
        pick = recognizer_markers(gt, self.spec) if self.task == "recognizer" else crosspoint_markers(gt, self.spec)[0]
        stored = load_npz(self.root / entry["samples"], only=(key,))[key]
        if not np.array_equal(gt.marker_id[pick], stored):
            raise ValueError(f"{self.root / entry['gt']}: its markers do not match the {self.task} crops of "
                             f"{self.root / entry['samples']}")
        if self.task == "recognizer":
            return {"points_px": gt.points_px[pick].astype(np.float64), key: stored}
        return {"pick": pick, key: stored}

    def _warp_markers(self, image_index: int) -> dict[str, np.ndarray]:
        """An image's markers as the view warp's cells need them: points off the fabric completed as
        `localizer_targets` completes them (without the crosspoints)."""
        gt = ImageGroundTruth.load(self.root / self.entries[image_index]["gt"])
        return {"points_px": completed_points(gt), "point_visible": gt.point_visible,
                "points_depth": gt.points_depth, "status": gt.status}

    def _warped_cells(self, image_index: int, view: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """The localizer's cell targets of an image seen through `view` (source -> item pixels) as an
        item of `size` (width, height), from the image's ground-truth points (`_warp_markers`)."""
        markers = self._markers[image_index]
        points = apply_homography(view, markers["points_px"]).astype(np.float32)  # NaN (off the fabric) stays NaN
        with np.errstate(invalid="ignore"):
            inside = ((points[:, 0] >= 0) & (points[:, 0] < np.asarray(size, np.float32))).all(axis=1)
        present = (markers["status"] > 0) & markers["point_visible"][:, 0] & inside
        return marker_cells(size[0], size[1], points, present, markers["points_depth"][:, 0])

    def _read_localizer(self, image_index: int) -> dict[str, np.ndarray]:
        """One image's localizer arrays as its files hold them: image (H, W, 3) uint8 RGB, cells
        (H/8, W/8, 11) float32."""
        entry = self.entries[image_index]
        path = self.root / entry["samples"]
        arrays = {"image": _read_png(self.root / entry["image"]), **load_npz(path, only=("cells",))}
        h, w = arrays["image"].shape[:2]
        if arrays["cells"].shape != (h // 8, w // 8, 11):
            raise ValueError(f"{path}: cells has shape {arrays['cells'].shape}, expected "
                             f"{(h // 8, w // 8, 11)} for the {w} x {h} image")
        return arrays

    def _keep(self, image_index: int, arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        self._cache[image_index] = arrays
        while len(self._cache) > self.cache_images:
            self._cache.popitem(last=False)
        return arrays


class SynthDataset(_Items, Dataset):
    """`length` items of `task` drawn from `PatternSynthesizer` (deterministic per seed, epoch, index).

    config: the synthesizer's settings (default `SynthConfig()`; for the crop tasks, which need one
    marker rather than a scene, 256 x 256 images centred on a marker); its seed is replaced by `seed`.  image_size
    overrides config.image_size.  For a crop task, item i takes crop i % crops_per_sample of
    synthetic sample i // crops_per_sample (a small cache makes consecutive items share a sample:
    sequential sampling, which loses nothing on i.i.d. synthetic data, profits from it).  Crosspoint
    items come from markers whose centre is visible, as the Detector's crops do (the factory's
    rendered crops also include markers seen only at their edge).
    codebook: (num_ids, n, n) codes of `spec` (generated if not given); marker_ids: the IDs that
    may appear (default all; `PatternSynthesizer`)."""

    #: item i is as random as any other, so a `MixedDataset` takes its items in order (and its cache hits)
    iid = True

    def __init__(self, task: str, spec: PatternSpec, length: int, seed: int, config: SynthConfig | None = None,
                 augment: Augment | None = None, image_size: tuple[int, int] | None = None,
                 codebook: np.ndarray | None = None, crops_per_sample: int = 2, marker_ids: np.ndarray | None = None):
        if task not in TASKS:
            raise ValueError(f"task must be one of {', '.join(TASKS)}, got {task!r}")
        if length < 1 or crops_per_sample < 1:
            raise ValueError(f"length and crops_per_sample must be >= 1, got {length}, {crops_per_sample}")
        if config is None:
            config = SynthConfig() if task == "localizer" else SynthConfig(image_size=(256, 256), centred=True)
        config = config.replace(seed=int(seed), **({"image_size": tuple(image_size)} if image_size else {}))
        self.task, self.spec, self.length, self.seed, self.augment = task, spec, int(length), int(seed), augment
        self.crops_per_sample = 1 if task == "localizer" else int(crops_per_sample)
        self.synthesizer = PatternSynthesizer(spec, config, codebook, marker_ids)
        self.codebook = self.synthesizer.codebook
        self._references = {}
        self._last: tuple[tuple[int, int], list[tuple]] | None = None

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        if not 0 <= index < self.length:
            raise IndexError(f"index {index} out of range for {self.length} items")
        sample = index // self.crops_per_sample
        base = (self.epoch * self.length + sample) * _ATTEMPTS
        if self.task == "localizer":
            image, gt = self.synthesizer.sample(base)
            return self._item(index, image=image, cells=localizer_targets(gt))
        crops = self._crops(sample, base)
        pick = self._rng(sample, 2).permutation(len(crops))[(index % self.crops_per_sample) % len(crops)]
        if self.task == "recognizer":
            crop, marker_id = crops[pick]
            return self._item(index, crop=crop, marker_id=marker_id)
        crop, marker_id, xy, visible = crops[pick]
        return self._item(index, crop=crop, marker_id=marker_id, xy=xy, visible=visible)

    def _crops(self, sample: int, base: int) -> list[tuple]:
        """The crops of the first of `_ATTEMPTS` synthetic samples that has any, as tuples."""
        key = (self.epoch, sample)
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        for attempt in range(_ATTEMPTS):
            made = synth_crops(self.task, *self.synthesizer.sample(base + attempt), self.spec,
                               self.synthesizer.config, base + attempt)
            if len(made[0]):
                crops = list(zip(*made))
                self._last = (key, crops)
                return crops
        raise RuntimeError(f"SynthDataset: {_ATTEMPTS} synthetic samples in a row showed no usable marker; "
                           f"check SynthConfig.marker_px against image_size ({self.synthesizer.config})")


def synth_crops(task: str, image: np.ndarray, gt, spec: PatternSpec, config: SynthConfig | None = None,
                index: int = 0, keep: Callable[[int], np.ndarray] | None = None) -> tuple[np.ndarray, ...]:
    """The crops of a crop task from a synthetic image and its ground truth: recognizer (crops, IDs),
    crosspoints (crops, IDs, xy, visible) of the markers whose centre is seen, as the Detector will
    see them (the localizer finds those); recognizer crops of partial markers too unless
    config.recognizer_partial is False (config None: the defaults).
    config.crop_jitter_px > 0: cut from jittered points (`ImageGroundTruth.jittered`), drawn from
    (config.seed, index).  keep: count -> the indices (sorted) of the crops to return, of the count
    there are; crosspoint crops are cut for those only (a synthetic image shows hundreds)."""
    config = config or SynthConfig()
    geometry = config.crop_geometry()
    if geometry.jitter_px > 0:
        gt = gt.jittered(geometry.jitter_px, np.random.default_rng([config.seed, int(index), _JITTER]))
    if task == "recognizer":
        made = recognizer_crops(image, gt, spec, partial=config.recognizer_partial)
        if keep is None:
            return made
        kept = keep(len(made[0]))  # drawn once: crops and IDs keep the same rows
        return tuple(array[kept] for array in made)
    chosen = crosspoint_centre_markers(gt, spec, geometry.crosspoints)
    if keep is not None:
        chosen = chosen[keep(len(chosen))]
    return crosspoint_crops(image, gt.select(chosen), spec, geometry.crosspoints)


class ShardDataset(_Items, Dataset):
    """The items of a shard folder of pre-synthesized samples (module docstring; `networks.shards`).

    Arrays are memory-mapped per worker on first use (the dataset pickles without them, so spawned
    DataLoader workers each open their own).  spec: the pattern to train on; the shards' codebook
    must be its codebook.  Items are augmented per (seed, epoch, index) as the other datasets'."""

    def __init__(self, root: str | Path, task: str, augment: Augment | None = None, spec: PatternSpec | None = None,
                 seed: int = 0):
        self.root, self.task, self.augment, self.seed = Path(root), task, augment, int(seed)
        self.meta = read_shard_meta(self.root)
        if self.meta["task"] != task:
            raise ValueError(f"{self.root / SHARD_META}: shards of the {self.meta['task']} task, not {task}")
        self.spec = PatternSpec.from_dict(self.meta["spec"], source=f"{self.root / SHARD_META}:spec")
        if spec is not None and codebook_hash(spec) != self.meta.get("codebook_hash"):
            raise ValueError(f"{self.root}: the shards were synthesized with another codebook than the pattern "
                             "to train on; write them with that pattern")
        self.marker_ids = None if self.meta.get("marker_ids") is None else np.asarray(self.meta["marker_ids"])
        self.parts = shard_parts(self.root)
        if not self.parts:
            raise ValueError(f"{self.root}: no finished part_NNNNN folders; write some with "
                             "`python -m networks.shards write`")
        counts = [len(next(iter(open_shard_part(part, task).values()))) for part in self.parts]
        self._starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.codebook = generate_codebook(self.spec) if task == "crosspoints" else None
        self._references = {}
        self._open: dict[int, dict[str, np.ndarray]] = {}

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_open": {}}  # memory maps are opened again in each worker

    def __len__(self) -> int:
        return int(self._starts[-1])

    def _part(self, number: int) -> dict[str, np.ndarray]:
        if number not in self._open:
            self._open[number] = open_shard_part(self.parts[number], self.task)
        return self._open[number]

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} items")
        number = int(np.searchsorted(self._starts, index, side="right")) - 1
        row = {name: np.array(array[index - self._starts[number]]) for name, array in self._part(number).items()}
        if self.task == "localizer":
            return self._item(index, image=row["image"], cells=row["cells"])
        return self._item(index, crop=row["crop"], marker_id=row["marker_id"], xy=row.get("xy"),
                          visible=row.get("visible"))


def open_shard_part(part: Path, task: str) -> dict[str, np.ndarray]:
    """The arrays `SHARD_ARRAYS[task]` of one shard part, memory-mapped (only their headers are read);
    ValueError naming the file when one is missing, unreadable or of another length than the first."""
    arrays: dict[str, np.ndarray] = {}
    for name in SHARD_ARRAYS[task]:
        path = part / f"{name}.npy"
        try:
            array = np.load(path, mmap_mode="r", allow_pickle=False)
        except FileNotFoundError:
            raise ValueError(f"{path}: missing (a {task} part holds {', '.join(SHARD_ARRAYS[task])})") from None
        except (OSError, EOFError, ValueError) as exc:
            raise ValueError(f"{path}: not a readable .npy array ({exc})") from None
        if array.ndim == 0:
            raise ValueError(f"{path}: a single value, expected one row per item")
        first = next(iter(arrays.values()), array)
        if len(array) != len(first):
            raise ValueError(f"{path}: {len(array)} items, the part's {SHARD_ARRAYS[task][0]}.npy has {len(first)}")
        arrays[name] = array
    return arrays


def read_shard_meta(root: str | Path) -> dict:
    """shards.json of a shard folder, checked to be one."""
    path = Path(root) / SHARD_META
    if not path.is_file():
        raise ValueError(f"{root}: no {SHARD_META} (not a shard folder of `python -m networks.shards write`)")
    meta = load_json(path)
    if not isinstance(meta, dict) or meta.get("format") != SHARD_FORMAT:
        raise ValueError(f"{path}: not a {SHARD_FORMAT} file")
    missing = [k for k in ("task", "spec", "codebook_hash", "synth", "images_per_part") if k not in meta]
    if missing or meta["task"] not in TASKS:
        raise ValueError(f"{path}: missing field(s) {', '.join(missing) or 'task'} or unknown task")
    synth = SynthConfig.from_dict(meta["synth"], source=f"{path}:synth")  # a removed option: refused by name
    if meta["task"] != "localizer":  # a folder written before the record: its crops as its synth config cut them
        written = synth.crop_geometry() if meta.get("crop_geometry") is None else CropGeometry.from_dict(
            meta["crop_geometry"], source=f"{path}:crop_geometry")
        if written.jitter_px != synth.crop_jitter_px:
            raise ValueError(f"{path}: crop_geometry.jitter_px is {written.jitter_px}, synth.crop_jitter_px "
                             f"{synth.crop_jitter_px}; the crops were cut with one of them")
        meta["crop_geometry"] = written.to_dict()
    return meta


def shard_geometry_problem(root: str | Path, meta: dict, geometry: CropGeometry) -> str | None:
    """Why a shard folder's crops (`read_shard_meta`'s crop_geometry) do not suit a run that cuts its
    crops with `geometry`, or None (also for localizer shards, which hold no crops)."""
    if meta.get("crop_geometry") is None:
        return None
    written = CropGeometry.from_dict(meta["crop_geometry"], source=f"{root}/{SHARD_META}:crop_geometry")
    if written == geometry:
        return None
    return (f"{root}: crops cut with another geometry than this run's ({'; '.join(written.differences(geometry))}, "
            f"shards vs run); write shards with --crop-jitter {geometry.jitter_px:g} or train with --crop-jitter "
            f"{written.jitter_px:g}")


def shard_parts(root: str | Path) -> list[Path]:
    """The finished parts of a shard folder, in order (unfinished ones are *.tmp folders)."""
    return sorted(p for p in Path(root).glob("part_*") if p.is_dir() and p.suffix != ".tmp")


class JoinedDataset(ConcatDataset):
    """Datasets of one task as one, item after item (a recipe's dataset folders); `set_epoch` reaches
    each of them."""

    def __init__(self, datasets: Sequence[Dataset]):
        super().__init__(datasets)
        tasks = {getattr(d, "task", None) for d in self.datasets}
        if len(tasks) != 1:
            raise ValueError(f"JoinedDataset: datasets of different tasks {sorted(map(str, tasks))}")
        self.task = tasks.pop()

    def set_epoch(self, epoch: int) -> None:
        for d in self.datasets:
            if hasattr(d, "set_epoch"):
                d.set_epoch(epoch)


class MixedDataset(Dataset):
    """`length` items, each drawn from `datasets[k]` with probability weights[k] (normalised) at a
    uniformly random index of it, or, from a dataset of i.i.d. items (``iid``, the synthesizer's), at
    item `index` itself: consecutive items of a batch then share its samples, whose crops a random
    index would render anew one crop at a time; deterministic per (seed, epoch, index)."""

    def __init__(self, datasets: Sequence[Dataset], weights: Sequence[float], length: int, seed: int):
        weights = np.asarray(weights, dtype=np.float64)
        if len(datasets) == 0 or weights.shape != (len(datasets),):
            raise ValueError(f"MixedDataset: need one weight per dataset, got {len(datasets)} datasets and "
                             f"weights {weights.tolist()}")
        if not (np.all(weights >= 0) and weights.sum() > 0):
            raise ValueError(f"MixedDataset: weights must be >= 0 with a positive sum, got {weights.tolist()}")
        tasks = {getattr(d, "task", None) for d in datasets}
        if len(tasks) > 1:
            raise ValueError(f"MixedDataset: datasets of different tasks {sorted(map(str, tasks))}")
        empty = [k for k, d in enumerate(datasets) if len(d) == 0 and weights[k] > 0]
        if empty or length < 1:
            raise ValueError(f"MixedDataset: length must be >= 1 ({length}) and weighted datasets non-empty ({empty})")
        self.datasets, self.weights = list(datasets), weights / weights.sum()
        self.task, self.length, self.seed, self.epoch = tasks.pop(), int(length), int(seed), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)
        for d in self.datasets:
            if hasattr(d, "set_epoch"):
                d.set_epoch(epoch)

    def __len__(self) -> int:
        return self.length

    def source(self, index: int) -> tuple[int, int]:
        """(dataset number, index in it) of item `index`."""
        if not 0 <= index < self.length:
            raise IndexError(f"index {index} out of range for {self.length} items")
        rng = np.random.default_rng([self.seed, self.epoch, int(index)])
        k = int(rng.choice(len(self.datasets), p=self.weights))
        if getattr(self.datasets[k], "iid", False):
            return k, int(index) % len(self.datasets[k])
        return k, int(rng.integers(len(self.datasets[k])))

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        k, j = self.source(index)
        return self.datasets[k][j]


# ---- files -----------------------------------------------------------------------------------------
def _manifest(root: Path) -> list[dict]:
    path = root / "manifest.jsonl"
    if not path.is_file():
        raise ValueError(f"{root}: no manifest.jsonl (not a factory dataset folder, or no shard has finished)")
    if not (root / "splits.json").is_file():
        raise ValueError(f"{root}: no splits.json (not a factory dataset folder)")
    entries = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}:{number}: invalid JSON ({exc.msg})") from exc
        missing = [k for k in ("name", "split", "image", "samples") if not isinstance(entry, dict) or k not in entry]
        if missing:
            raise ValueError(f"{path}:{number}: missing field(s) {', '.join(missing)}")
        entries.append(entry)
    return entries


def write_training_samples(root: Path, entry: dict, spec: PatternSpec) -> None:
    """`root / entry["samples"]` (`training_samples`: cells and crops) from the manifest entry's image and
    ground truth, for a dataset folder that travelled without its samples/."""
    image = _read_png(root / entry["image"])
    save_npz(root / entry["samples"], training_samples(image, ImageGroundTruth.load(root / entry["gt"]), spec))


def _read_png(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    return np.ascontiguousarray(image[:, :, ::-1])


def _chw(image: np.ndarray) -> torch.Tensor:
    """(H, W, 3) uint8 -> (3, H, W) uint8 tensor."""
    return torch.from_numpy(np.ascontiguousarray(np.asarray(image, np.uint8).transpose(2, 0, 1)))
