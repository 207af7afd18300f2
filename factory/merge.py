"""Merge factory datasets into one folder: `python -m factory.dataset merge SRC [SRC ...] --out OUT`.

Datasets built apart (other frames, motions, seeds, machines) become one set the networks read as
one: `networks.train --data OUT`, `benchmarks/networks.py --rendered OUT`.  Each image keeps its
files and record, and its name unless an earlier source holds an image of that name with other
pixels (two builds of the same motion and frames with other seeds name their images alike): then
it is renamed `<name>_m<k>` (k: its source's position, from 1) with its files, and its record keeps
the old name as "source_name".  `--train SRC` puts every image of that source in the train split
(more training images beside a set whose held-out split stays as it was, so results stay comparable).

Refused, naming the files:
- sources whose `template.npz` differ (another garment, level or pattern: their marker IDs and
  ground truth do not mean the same);
- an image in two sources with the same name and the same pixels (a dataset merged twice);
- a simulation frame (motion/frame) of one simulation in two splits, which would put the same garment
  geometry in training and in evaluation.  An image's simulation is its record's "simulation"
  (`factory.simulate.SimulationConfig.key()`, written by the build); records without one (built
  before it was) count as every simulation's, so their frames are refused as before.

OUT gets `template.npz` and `texture.png` (from the first source), `images/`, `gt/`, `samples/` (where
a source has them: built from the images otherwise, as `networks` does), `meta/`, `manifest.jsonl`,
`splits.json` and `config.json` (`{"merged": [per source: its folder, config, image count, train]}`),
not the sources' simulations, scenes and render jobs.  Files are hard links where the file system
allows, copies otherwise; each is written atomically and an image's record last, so an interrupted
merge is finished by running it again, and a second run with other sources is refused.
"""

from __future__ import annotations

import filecmp
import os
import shutil
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from tqdm import tqdm

from assets.fileio import atomic_path, load_json, record_stage, save_json
from factory.plan import SPLITS
from factory.shards import write_manifest

#: an image record's fields that name its files
FILE_FIELDS = ("image", "depth", "camera", "gt", "samples")
#: the folder-level files taken from the first source
SHARED_FILES = ("template.npz", "texture.png")


@dataclass(frozen=True)
class Source:
    """One dataset folder to merge (a path); train: all its images go to the train split."""
    folder: Path
    train: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "folder", Path(self.folder))


def _records(folder: Path) -> list[dict]:
    """The finished images' records (`meta/<name>.json`, as `factory.shards.write_manifest` lists them)."""
    if not (folder / "template.npz").is_file() or not (folder / "meta").is_dir():
        raise ValueError(f"{folder}: not a factory dataset folder (no template.npz or meta/)")
    records = [load_json(p) for p in sorted((folder / "meta").glob("*.json"))]
    if not records:
        raise ValueError(f"{folder}: no finished image (meta/ is empty)")
    return records


def _place(source: Path, target: Path) -> None:
    """`target` as a hard link to `source`, or a copy where linking fails (another file system)."""
    if target.exists():  # a rerun: the same file (linked), or one with the same bytes (copied)
        if not (os.path.samefile(source, target) or filecmp.cmp(source, target, shallow=False)):
            raise ValueError(f"{target} exists and differs from {source}")
        return
    with atomic_path(target) as tmp:
        tmp.unlink()
        try:
            os.link(source, tmp)
        except OSError:
            shutil.copy2(source, tmp)


def _renamed(record: dict, name: str) -> dict:
    """`record` as image `name`: its file fields' names start with the new name instead of the old."""
    old = record["name"]
    renamed = {**record, "name": name, "source_name": record.get("source_name", old)}
    for field in FILE_FIELDS:
        if field in record:
            path = PurePosixPath(record[field])
            if not path.name.startswith(old):
                raise ValueError(f"image {old}: its {field} file {record[field]} is not named after it")
            renamed[field] = str(path.with_name(name + path.name[len(old):]))
    return renamed


def _simulations(first: str | None, second: str | None) -> str:
    """How two records' simulation keys make them the same simulation, for a refusal."""
    if first is not None and second is not None:
        return f"both of simulation {first}"
    return "a record without a simulation key, from a build before records had one, counts as the same"


def merge(out: str | Path, sources: list[Source], progress: bool = True) -> Path:
    """Merge `sources` into the folder `out` (layout above); returns its manifest.jsonl."""
    out = Path(out)
    if len(sources) < 1:
        raise ValueError("merge needs at least one source dataset folder")
    first = sources[0].folder / "template.npz"
    plan, names, frames, counts = [], {}, {}, []
    for k, source in enumerate(sources, start=1):
        records = _records(source.folder)
        template = source.folder / "template.npz"
        if not filecmp.cmp(first, template, shallow=False):
            raise ValueError(f"{template} differs from {first}: another garment, level or pattern, whose marker IDs "
                             "and ground truth do not mean the same")
        for original in records:
            record = {**original, "split": "train"} if source.train else original
            name = record["name"]
            if name in names:
                folder, earlier = names[name]
                if filecmp.cmp(folder / earlier["image"], source.folder / record["image"], shallow=False):
                    raise ValueError(f"image {name} is in both {folder} and {source.folder} with the same pixels: "
                                     "the same dataset merged twice")
                record = _renamed(record, f"{name}_m{k}")
                if record["name"] in names:
                    raise ValueError(f"image {name} of {source.folder} cannot be renamed {record['name']}: "
                                     f"{names[record['name']][0]} holds an image of that name")
            names[record["name"]] = (source.folder, original)
            frame, simulation = f"{record['motion']}/{record['frame']}", record.get("simulation")
            seen = frames.setdefault(frame, {})  # (split, simulation) -> the first folder with it
            for (split, other), where in seen.items():
                if split != record["split"] and (simulation is None or other is None or other == simulation):
                    raise ValueError(f"simulation frame {frame} is {split} in {where} and {record['split']} in "
                                     f"{source.folder} ({_simulations(other, simulation)}): the same garment "
                                     "geometry would be trained on and evaluated")
            seen.setdefault((record["split"], simulation), source.folder)
            plan.append((source.folder, original, record))
        counts.append(len(records))
    config = {"merged": [{"folder": str(s.folder.resolve()), "train": s.train, "images": count,
                          "config": load_json(s.folder / "config.json") if (s.folder / "config.json").is_file() else None}
                         for s, count in zip(sources, counts)]}
    record_stage(out / "config.json", config)  # a folder of another dataset or merge is refused
    for name in SHARED_FILES:
        if (sources[0].folder / name).is_file():
            _place(sources[0].folder / name, out / name)
    for folder, original, record in tqdm(plan, desc="merge", unit="image", disable=not progress):
        for field in FILE_FIELDS:
            if field in record and (folder / original[field]).is_file():
                _place(folder / original[field], out / record[field])
        meta = out / "meta" / f"{record['name']}.json"
        if not meta.exists() or load_json(meta) != record:
            save_json(meta, record)
    splits = {s: sorted(f for f, seen in frames.items() if any(split == s for split, _ in seen)) for s in SPLITS}
    save_json(out / "splits.json", splits)
    return write_manifest(out)
