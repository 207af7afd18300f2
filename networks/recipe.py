"""Network recipes: the `[networks.<task>]` tables of a recipe file, as training runs.

    python -m factory.dataset build --recipe modules_reader --out out/datasets/modules_reader
    python -m networks.train --recipe modules_reader --data out/datasets/modules_reader --out runs/reader

A recipe file (`networks/recipes/NAME.toml`, found by `assets.recipes`) holds a shipped network's
whole making: `[data]`, the renders (`factory.recipe`), and per network a table of `TrainConfig`
fields (the task is the table's name) plus two of its own::

    [networks.recognizer]
    data = "rendered"            # the recipe's training parts, mixed with the synthesizer at synth_weight;
                                 # "synth": the synthesizer alone
    recognizer_classes = "modules"
    steps = 8000

    [networks.recognizer.init]   # start from stored weights, pinned: a commit of the repository's history
    commit = "48d0ed67..."       # (`networks.weights`), the file there and its SHA-256; or leave it out
    file = "recognizer.pt"
    sha256 = "c48c5c1d..."

Fields a table leaves out take `TrainConfig`'s defaults, so the file is the whole config only
together with the commit that reads it; a run therefore saves the recipe's name, its file's digest
and the commit beside its config (`recipe.json` in the run folder).  A rendered run checks that its
data folder was built from this recipe's `[data]` table (its digest in the folder's `recipe.json`),
and its `init` is checked against the SHA-256 pinned in the recipe, so a run never starts from
other weights or data than the recipe names (weights stored later do not change what it starts from).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from assets.fileio import check_json_object
from assets.recipes import BUILD_RECORD, read_build, read_recipe, table_digest
from networks.config import TASKS, TrainConfig
from networks.weights import fetch_blob, file_sha256

#: a recipe network's sources of training data
DATA_SOURCES = ("rendered", "synth")
#: the keys of a recipe network's `init` table: stored weights pinned in the repository's history
INIT_KEYS = ("commit", "file", "sha256")


@dataclass(frozen=True)
class StoredInit:
    """Weights a recipe network starts from: `file` of commit `commit` of the repository's history
    (where `networks.weights store` keeps them), whose bytes have SHA-256 `sha256`."""

    commit: str
    file: str
    sha256: str

    @classmethod
    def from_table(cls, table: object, where: str) -> "StoredInit":
        if not isinstance(table, dict) or sorted(table) != sorted(INIT_KEYS) or \
                not all(isinstance(v, str) and v for v in table.values()):
            raise ValueError(f"{where}: init must be a table of {', '.join(INIT_KEYS)} (stored weights pinned in "
                             f"the repository's history, networks/weights.json lists them), got {table!r}")
        hexadecimal = set("0123456789abcdef")
        if len(table["commit"]) != 40 or len(table["sha256"]) != 64 or \
                not set(table["commit"] + table["sha256"]) <= hexadecimal:
            raise ValueError(f"{where}: init.commit must be 40 and init.sha256 64 lowercase hex digits")
        return cls(table["commit"], table["file"], table["sha256"])


@dataclass(frozen=True)
class NetworkRecipe:
    """One network of a recipe: its training config, where its data comes from (`DATA_SOURCES`) and
    the stored weights it starts from (or None)."""

    config: TrainConfig
    data: str = "rendered"
    init: StoredInit | None = None

    @classmethod
    def from_table(cls, task: str, table: object, source: str) -> "NetworkRecipe":
        where = f"{source} [networks.{task}]"
        if not isinstance(table, dict):
            raise ValueError(f"{where}: expected a table, got {type(table).__name__}")
        table = dict(table)
        data = table.pop("data", "rendered")
        if data not in DATA_SOURCES:
            raise ValueError(f"{where}: data must be one of {', '.join(DATA_SOURCES)}, got {data!r}")
        init = table.pop("init", None)
        stored = None if init is None else StoredInit.from_table(init, where)
        if "task" in table:
            raise ValueError(f"{where}: the table's name is the task; remove 'task'")
        if data == "synth" and table.get("synth_weight", 1.0) != 1.0:
            raise ValueError(f"{where}: data 'synth' trains on the synthesizer alone; synth_weight must be 1 or absent")
        check_json_object(table, [f.name for f in dataclasses.fields(TrainConfig)], where)
        try:  # fields left out take TrainConfig's defaults (from_dict reads old saved configs otherwise)
            config = TrainConfig(task=task, **table)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None
        if data == "synth":
            config = config.replace(synth_weight=1.0)
        return cls(config, data, stored)

    def to_table(self) -> dict:
        """The table that reads back as this recipe (every TrainConfig field written out)."""
        table = {k: v for k, v in self.config.to_dict().items() if k not in ("task", "init") and v is not None}
        table["data"] = self.data
        if self.init is not None:
            table["init"] = dataclasses.asdict(self.init)
        return table


@dataclass(frozen=True)
class Recipe:
    """A recipe file: its name, file, `[data]` table (as read; `factory.recipe` builds it) and networks."""

    name: str
    path: Path
    data: dict | None
    networks: dict[str, NetworkRecipe]

    @property
    def data_digest(self) -> str | None:
        return None if self.data is None else table_digest(self.data)

    def network(self, task: str | None) -> tuple[str, NetworkRecipe]:
        """(task, its recipe): `task`, or the recipe's only network when None."""
        if task is None:
            if len(self.networks) != 1:
                raise ValueError(f"{self.path}: trains {', '.join(self.networks)}; name the task to train")
            task = next(iter(self.networks))
        if task not in self.networks:
            raise ValueError(f"{self.path}: no [networks.{task}] table (it trains {', '.join(self.networks)})")
        return task, self.networks[task]

    def record(self, task: str) -> dict:
        """What a run of `task` saves beside its config: the recipe, its file's SHA-256, its tables."""
        return {"recipe": self.name, "file_sha256": file_sha256(self.path),
                "data_digest": self.data_digest, "task": task, "network": self.networks[task].to_table()}


def load_recipe(name: str | Path) -> Recipe:
    """Read and check recipe `name` (a name in networks/recipes or a .toml path)."""
    path, tables = read_recipe(name)
    unknown = sorted(set(tables) - {"data", "networks", "description"})
    if unknown:
        raise ValueError(f"{path}: unknown table(s) {', '.join(unknown)} (a recipe has [data] and [networks.<task>])")
    networks = tables.get("networks")
    if not isinstance(networks, dict) or not networks:
        raise ValueError(f"{path}: no [networks.<task>] table ({', '.join(TASKS)})")
    if unknown := sorted(set(networks) - set(TASKS)):
        raise ValueError(f"{path}: [networks.{unknown[0]}] is not a network ({', '.join(TASKS)})")
    parsed = {task: NetworkRecipe.from_table(task, table, str(path)) for task, table in networks.items()}
    rendered = [task for task, recipe in parsed.items() if recipe.data == "rendered"]
    if rendered and "data" not in tables:
        raise ValueError(f"{path}: {', '.join(rendered)} train(s) on renders, but the recipe has no [data] table")
    return Recipe(path.stem, path, tables.get("data"), parsed)


def stored_init(network: NetworkRecipe, task: str, given: str | Path | None, cache: str | Path) -> Path | None:
    """The checkpoint a recipe network starts from: None without an `init`; else `given` (a file whose
    SHA-256 must be the pinned one, for a machine without the repository's history), or the pinned
    weights written from the history into `cache` (`networks.weights.fetch_blob`)."""
    if network.init is None:
        if given is not None:
            raise ValueError(f"the recipe's {task} starts from no stored weights; leave out --init")
        return None
    init = network.init
    if given is None:
        root = Path(__file__).resolve().parents[1]
        return fetch_blob(root, init.commit, init.file, init.sha256, Path(cache) / init.file, f"{task} init")
    given = Path(given)
    if not given.is_file():
        raise FileNotFoundError(f"{given}: no such checkpoint (--init)")
    if file_sha256(given) != init.sha256:
        raise ValueError(f"{given}: not the weights the recipe's {task} starts from (SHA-256 {init.sha256[:12]}..., "
                         f"{init.commit[:12]}:{init.file}); leave out --init to write them from the history")
    return given


def check_data_folder(recipe: Recipe, folder: str | Path) -> list[Path]:
    """The training part folders of `folder`, a build of `recipe`'s data; refused, naming the folder, when
    it was built from another recipe or another `[data]` table."""
    folder = Path(folder)
    record_path = folder / BUILD_RECORD
    if not record_path.is_file():
        raise FileNotFoundError(f"{folder}: no {BUILD_RECORD}; build the data with "
                                f"python -m factory.dataset build --recipe {recipe.name} --out {folder}")
    record = read_build(folder)
    if record.get("data_digest") != recipe.data_digest:
        raise ValueError(f"{record_path}: built from recipe {record.get('recipe')!r} with another [data] table "
                         f"than {recipe.path}'s; rebuild it or train on the folder made from this recipe")
    parts = record["parts"].get("train")
    if not isinstance(parts, list) or not parts:
        raise ValueError(f"{record_path}: lists no training parts")
    missing = [p for p in parts if not (folder / p / "manifest.jsonl").is_file()]
    if missing:
        raise ValueError(f"{folder}: unfinished parts {', '.join(missing)}; run factory.dataset build --recipe "
                         f"{recipe.name} --out {folder} again")
    return [folder / p for p in parts]


__all__ = ["DATA_SOURCES", "NetworkRecipe", "Recipe", "StoredInit", "check_data_folder", "load_recipe", "stored_init"]
