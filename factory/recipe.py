"""Data recipes: the `[data]` table of a network recipe file, as factory dataset builds.

    python -m factory.dataset build --recipe modules_reader --out out/datasets/modules_reader

A recipe file (`networks/recipes/NAME.toml`; `networks.recipe` reads its `[networks.*]` tables) says
which renders a network was trained on, so that anyone can make them again::

    [data]
    garments = ["shirt", "assets/data/garmentcode/shirt_mean_specification.json"]
    motions = ["walk", "arm_swing", "assets/data/motions/cmu_93_03_charleston.bvh"]
    frames = 8            # per motion, frame_step simulation frames apart (DatasetConfig)
    variations = 5        # the reference's: 5 images per frame, 10 environments, split 22:2:1
    motions_per_part = 2  # optional: each training part takes 2 of the motions, in turn (default: all)
    [[data.bodies]]
    name = "default"      # a label: the part folders' names
    body = "default"      # "default" or a body file
    betas = [0.5, 0.5, 0.5]   # optional shape values (default: the motion's, else the body's)
    [data.render]         # RenderSettings fields
    samples = 64
    [data.holdout]        # never trained on: evaluation only
    frames = 2
    garments = ["assets/data/garmentcode/hoody_mean_specification.json"]
    motions = ["squat"]
    bodies = ["tall"]     # labels of [[data.bodies]] entries

Motions are built-in motion names or motion files (`.bvh`, AMASS or saved `.npz`), named in folders
by `assets.motion.sources.motion_label` (a file's stem).  Relative garment, body and motion paths are
relative to the repository's root (the folder holding `networks/recipes`).  A dataset folder is not a
garment-mixing store (ground truth refers to one template), so a recipe builds one dataset folder per
part (`parts`):
- `train/<garment>-<body>`: each training garment on each training body over the training motions, or,
  with `motions_per_part` k, over k of them in turn: part (garment g, body b) takes the k motions
  starting at (g + b) * k (cyclically), so every garment and every body still meets every motion when
  there are enough parts, at a fraction of the simulations and renders;
- `holdout/<garment>-<body>`: each held-out garment on the first training body, and the first training
  garment on each held-out body, both over the first training motion and the held-out motions; and
  the first training garment and body over the held-out motions alone (`holdout-motions`); each
  `holdout.frames` frames (default: `frames`).
Every part is an ordinary `factory.build` dataset (resumable, its own `config.json` check), and the
folder gets `recipe.json` (the recipe's name, its `[data]` table and that table's digest), which
`networks.train --recipe` checks, so a run never trains on data of another recipe.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

from assets.fileio import check_json_object, record_stage, safe_name
from assets.recipes import BUILD_RECORD, ROOT, read_recipe, table_digest
from factory.build import build
from factory.plan import DatasetConfig, RenderSettings

#: part folders of the training and of the evaluation data
TRAIN, HOLDOUT = "train", "holdout"


def _strings(table: dict, key: str, source: str, required: bool = True) -> tuple[str, ...]:
    value = table.get(key, None if required else [])
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value) or (required and not value):
        raise ValueError(f"{source}: {key} must be a {'non-empty ' if required else ''}list of names, got {value!r}")
    if len(set(value)) != len(value):
        raise ValueError(f"{source}: {key} names one item twice: {value}")
    return tuple(value)


def _input_path(spec: str) -> str:
    """A garment, body or motion spec: a name as it is, a path resolved against the repository's root
    (so a recipe builds the same data from any working directory)."""
    if "/" not in spec and not spec.endswith((".json", ".npz", ".pkl", ".bvh")):
        return spec
    path = Path(spec)
    return str(path if path.is_absolute() else ROOT / path)


def garment_label(spec: str) -> str:
    """A garment's name in part folders: its name, or its file's stem without `_specification`."""
    stem = Path(spec).stem
    return stem[: -len("_specification")] if stem.endswith("_specification") else stem


@dataclass(frozen=True)
class BodyShape:
    """One body of a recipe: `name` labels its folders; `body` is "default" or a body file; `betas`
    its shape values (None: the motion's own, else the body's defaults)."""

    name: str
    body: str = "default"
    betas: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Part:
    """One dataset folder of a recipe: `folder` relative to the recipe's output, and its build."""

    folder: str
    config: DatasetConfig


@dataclass(frozen=True)
class DataRecipe:
    """A recipe's `[data]` table (see the module docstring); the DatasetConfig fields it does not name
    take their defaults."""

    garments: tuple[str, ...]
    motions: tuple[str, ...]
    bodies: tuple[BodyShape, ...] = (BodyShape("default"),)
    frames: int = DatasetConfig.frames
    frame_step: int = DatasetConfig.frame_step
    variations: int = DatasetConfig.variations
    seed: int = 0
    render: RenderSettings = field(default_factory=RenderSettings)
    holdout_garments: tuple[str, ...] = ()
    holdout_motions: tuple[str, ...] = ()
    holdout_bodies: tuple[str, ...] = ()
    holdout_frames: int | None = None
    motions_per_part: int | None = None

    @classmethod
    def from_table(cls, table: object, source: str) -> "DataRecipe":
        """Read a `[data]` table; unknown keys and bad values are refused naming `source` and the key."""
        keys = ("garments", "motions", "bodies", "frames", "frame_step", "variations", "seed", "render", "holdout",
                "motions_per_part")
        table = check_json_object(table, keys, f"{source} [data]")
        where = f"{source} [data]"
        numbers = {}
        for key, low in (("frames", 1), ("frame_step", 1), ("variations", 1), ("seed", 0)):
            value = table.get(key, getattr(cls, key))
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"{where}: {key} must be an integer >= {low}, got {value!r}")
            numbers[key] = value
        per_part = table.get("motions_per_part")
        if per_part is not None and (not isinstance(per_part, int) or isinstance(per_part, bool) or per_part < 1):
            raise ValueError(f"{where}: motions_per_part must be an integer >= 1, got {per_part!r}")
        bodies = []
        for k, entry in enumerate(table.get("bodies", [{"name": "default"}])):
            at = f"{where} bodies[{k}]"
            entry = check_json_object(entry, ("name", "body", "betas"), at)
            betas = entry.get("betas")
            if betas is not None and not (isinstance(betas, list) and betas and all(
                    isinstance(b, (int, float)) and not isinstance(b, bool) for b in betas)):
                raise ValueError(f"{at}: betas must be a list of numbers, got {betas!r}")
            body = entry.get("body", "default")
            if not isinstance(body, str) or not body:
                raise ValueError(f"{at}: body must be 'default' or a body file, got {body!r}")
            bodies.append(BodyShape(safe_name(entry.get("name"), f"{at} name"), body,
                                    None if betas is None else tuple(float(b) for b in betas)))
        if not bodies or len({b.name for b in bodies}) != len(bodies):
            raise ValueError(f"{where}: bodies must be a non-empty list with distinct names")
        render = table.get("render", {})
        render = check_json_object(render, [f.name for f in fields(RenderSettings)], f"{where} render")
        try:
            render = RenderSettings(**{k: tuple(v) if k == "resolution" else v for k, v in render.items()})
        except TypeError as exc:
            raise ValueError(f"{where} render: {exc}") from None
        holdout = check_json_object(table.get("holdout", {}), ("garments", "motions", "bodies", "frames"),
                                    f"{where} holdout")
        held_frames = holdout.get("frames")
        if held_frames is not None and (not isinstance(held_frames, int) or isinstance(held_frames, bool)
                                        or held_frames < 1):
            raise ValueError(f"{where} holdout: frames must be an integer >= 1, got {held_frames!r}")
        recipe = cls(garments=_strings(table, "garments", where), motions=_strings(table, "motions", where),
                     bodies=tuple(bodies), render=render, **numbers,
                     holdout_garments=_strings(holdout, "garments", f"{where} holdout", False),
                     holdout_motions=_strings(holdout, "motions", f"{where} holdout", False),
                     holdout_bodies=_strings(holdout, "bodies", f"{where} holdout", False),
                     holdout_frames=held_frames, motions_per_part=per_part)
        recipe.check(where)
        return recipe

    def check(self, where: str) -> None:
        """Refuse a hold-out that overlaps training or names a body the recipe does not define."""
        names = [b.name for b in self.bodies]
        for kind, held, used in (("garments", self.holdout_garments, self.garments),
                                 ("motions", self.holdout_motions, self.motions)):
            if overlap := sorted(set(held) & set(used)):
                raise ValueError(f"{where}: holdout {kind} {overlap} are also trained on")
        if unknown := sorted(set(self.holdout_bodies) - set(names)):
            raise ValueError(f"{where}: holdout bodies {unknown} are not among the bodies ({', '.join(names)})")
        if self.motions_per_part is not None and self.motions_per_part > len(self.motions):
            raise ValueError(f"{where}: motions_per_part {self.motions_per_part} is more than the "
                             f"{len(self.motions)} training motions")
        if set(names) <= set(self.holdout_bodies):
            raise ValueError(f"{where}: every body is held out; nothing is left to train on")
        labels = [garment_label(g) for g in self.garments + self.holdout_garments]
        if len(set(labels)) != len(labels):
            raise ValueError(f"{where}: two garments share the folder name in {labels}")

    def _config(self, garment: str, body: BodyShape, motions: tuple[str, ...], held: bool = False) -> DatasetConfig:
        frames = self.holdout_frames if held and self.holdout_frames else self.frames
        return DatasetConfig(garment=_input_path(garment), motions=tuple(_input_path(m) for m in motions),
                             body=_input_path(body.body),
                             betas=body.betas, frames=frames, frame_step=self.frame_step,
                             variations=self.variations, seed=self.seed, render=self.render)

    def part_motions(self, garment: int, body: int) -> tuple[str, ...]:
        """The training motions of training part (garment index, training body index)."""
        k = self.motions_per_part
        if k is None or k >= len(self.motions):
            return self.motions
        start = (garment + body) * k
        return tuple(self.motions[(start + n) % len(self.motions)] for n in range(k))

    def parts(self) -> list[Part]:
        """The dataset folders of this recipe, training parts first (see the module docstring)."""
        training = [b for b in self.bodies if b.name not in self.holdout_bodies]
        held = [b for b in self.bodies if b.name in self.holdout_bodies]
        shown = self.motions[:1] + self.holdout_motions
        parts = [Part(f"{TRAIN}/{garment_label(g)}-{b.name}", self._config(g, b, self.part_motions(i, j)))
                 for i, g in enumerate(self.garments) for j, b in enumerate(training)]
        first_garment, first_body = self.garments[0], training[0]
        parts += [Part(f"{HOLDOUT}/{garment_label(g)}-{first_body.name}", self._config(g, first_body, shown, True))
                  for g in self.holdout_garments]
        parts += [Part(f"{HOLDOUT}/{garment_label(first_garment)}-{b.name}",
                       self._config(first_garment, b, shown, True)) for b in held]
        if self.holdout_motions:
            parts.append(Part(f"{HOLDOUT}/{garment_label(first_garment)}-{first_body.name}-motions",
                              self._config(first_garment, first_body, self.holdout_motions, True)))
        return parts


def load_data_recipe(name: str | Path) -> tuple[Path, dict, DataRecipe]:
    """(file, raw `[data]` table, DataRecipe) of recipe `name`."""
    path, tables = read_recipe(name)
    if "data" not in tables:
        raise ValueError(f"{path}: no [data] table (the renders the recipe's networks train on)")
    return path, tables["data"], DataRecipe.from_table(tables["data"], str(path))


def build_recipe(name: str | Path, out: str | Path, shard: tuple[int, int] = (0, 1), holdout: bool = True,
                 **build_options: object) -> list[Path]:
    """Build every part of recipe `name` under `out` (`factory.build.build` per part, with
    `build_options`); `holdout` False builds the training parts only.  Returns the part folders."""
    path, table, recipe = load_data_recipe(name)
    out = Path(out)
    parts = recipe.parts()
    record = {"recipe": path.stem, "data": table, "data_digest": table_digest(table),
              "parts": {kind: [p.folder for p in parts if p.folder.startswith(kind + "/")] for kind in (TRAIN, HOLDOUT)}}
    record_stage(out / BUILD_RECORD, record)  # another recipe's folder is refused before anything is built
    folders = []
    for part in parts:
        if not holdout and part.folder.startswith(HOLDOUT):
            continue
        build(part.config, out / part.folder, shard, **build_options)
        folders.append(out / part.folder)
    return folders


__all__ = ["BodyShape", "DataRecipe", "Part", "build_recipe", "garment_label", "load_data_recipe"]
