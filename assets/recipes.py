"""Recipe files (`networks/recipes/NAME.toml`): where they are found and how they are read.

A recipe holds everything that made a shipped network: its renders (`[data]`, read by
`factory.recipe`) and its training runs (`[networks.<task>]`, read by `networks.recipe`).  Both
halves read the file through here, so a name means the same file to each, and a table's digest is
the same number on the machine that built the data and on the one that trains on it.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from pathlib import Path

from assets.fileio import load_json, safe_name

#: the repository's root: relative paths in recipes start here
ROOT = Path(__file__).resolve().parent.parent
#: where recipe names are looked up
RECIPES = ROOT / "networks" / "recipes"
#: the record `factory.dataset build --recipe` writes into its output folder: the recipe's name, its
#: `[data]` table and that table's digest, and its part folders ({"train": [...], "holdout": [...]})
BUILD_RECORD = "recipe.json"


def recipe_path(name: str | Path) -> Path:
    """The file of recipe `name`: a path to a .toml file, or a name in `RECIPES`."""
    path = Path(name)
    if path.suffix == ".toml" or len(path.parts) > 1:
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such recipe file")
        return path
    path = RECIPES / f"{safe_name(str(name), '--recipe')}.toml"
    if not path.is_file():
        known = sorted(p.stem for p in RECIPES.glob("*.toml"))
        raise FileNotFoundError(f"no recipe named {name!r} in {RECIPES} (known: {', '.join(known) or 'none'})")
    return path


def read_recipe(name: str | Path) -> tuple[Path, dict]:
    """(the file, its tables) of recipe `name`; a ValueError naming the file for TOML it cannot read."""
    path = recipe_path(name)
    try:
        with open(path, "rb") as handle:
            return path, tomllib.load(handle)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not a TOML recipe ({exc})") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc})") from None


def read_build(folder: str | Path) -> dict:
    """The `BUILD_RECORD` of a recipe build folder; FileNotFoundError naming the folder without one."""
    path = Path(folder) / BUILD_RECORD
    if not path.is_file():
        raise FileNotFoundError(f"{folder}: no {BUILD_RECORD} (not built by factory.dataset build --recipe)")
    record = load_json(path)
    if not isinstance(record, dict) or not isinstance(record.get("parts"), dict):
        raise ValueError(f"{path}: not the record of a recipe build (no parts)")
    return record


def table_digest(table: object) -> str:
    """SHA-256 of a recipe table as canonical JSON: the same table, the same digest (key order aside)."""
    return hashlib.sha256(json.dumps(table, sort_keys=True, separators=(",", ":")).encode()).hexdigest()
