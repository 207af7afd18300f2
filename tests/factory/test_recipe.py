"""Data recipes: the shipped recipes' [data] tables read, their parts follow the hold-out rules, motion
files are named from the repository's root, bad tables are refused naming the file and key, and a
folder of another recipe is never built into."""

from pathlib import Path

import pytest

from assets.body import default_body
from assets.motion import Motion
from assets.motion.sources import load_motion, motion_label
from assets.recipes import RECIPES, ROOT, read_recipe, table_digest
from factory.recipe import DataRecipe, build_recipe, load_data_recipe

SHIPPED = sorted(RECIPES.glob("*.toml"))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_shipped_recipe_reads(path):
    _, table, recipe = load_data_recipe(path.stem)
    assert recipe == DataRecipe.from_table(table, str(path))
    parts = recipe.parts()
    assert parts and all(p.folder.startswith(("train/", "holdout/")) for p in parts)
    trained = {p.config.garment for p in parts if p.folder.startswith("train/")}
    held = {p.config.garment for p in parts if p.folder.startswith("holdout/")} - trained
    assert len(held) == len(recipe.holdout_garments)  # held-out garments never reach a training part
    files = {m for p in parts for m in p.config.motions if m.endswith((".bvh", ".npz"))}
    assert all(Path(m).is_absolute() and Path(m).is_file() for m in files), files


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "r.toml"
    path.write_text(text)
    return path


BASE = """
[data]
garments = ["shirt", "skirt"]
motions = ["walk", "run"]
frames = 3
[[data.bodies]]
name = "default"
[[data.bodies]]
name = "tall"
betas = [0.5, 0.9, 0.5]
[data.holdout]
frames = 1
garments = ["pants"]
motions = ["squat"]
bodies = ["tall"]
"""


def test_parts_hold_out_a_garment_a_body_and_a_motion(tmp_path):
    _, _, recipe = load_data_recipe(_write(tmp_path, BASE))
    parts = {p.folder: p.config for p in recipe.parts()}
    assert list(parts) == ["train/shirt-default", "train/skirt-default", "holdout/pants-default",
                           "holdout/shirt-tall", "holdout/shirt-default-motions"]
    assert parts["train/skirt-default"].motions == ("walk", "run") and parts["train/skirt-default"].frames == 3
    assert parts["holdout/pants-default"].motions == ("walk", "squat") and parts["holdout/pants-default"].frames == 1
    assert parts["holdout/shirt-tall"].betas == (0.5, 0.9, 0.5)
    assert parts["holdout/shirt-default-motions"].motions == ("squat",)
    assert all(c.betas is None for f, c in parts.items() if f != "holdout/shirt-tall")


def test_motions_per_part_turn_so_every_garment_and_body_meets_every_motion(tmp_path):
    four = BASE.replace('motions = ["walk", "run"]', 'motions = ["walk", "run", "bend", "arm_swing"]\nmotions_per_part = 2')
    four = four.replace('bodies = ["tall"]', 'bodies = []')  # both bodies train
    _, _, recipe = load_data_recipe(_write(tmp_path, four))
    train = {p.folder: p.config.motions for p in recipe.parts() if p.folder.startswith("train/")}
    assert train == {"train/shirt-default": ("walk", "run"), "train/shirt-tall": ("bend", "arm_swing"),
                     "train/skirt-default": ("bend", "arm_swing"), "train/skirt-tall": ("walk", "run")}
    held = {p.folder: p.config.motions for p in recipe.parts() if p.folder.startswith("holdout/")}
    assert held["holdout/pants-default"] == ("walk", "squat")  # hold-out parts are not thinned
    with pytest.raises(ValueError, match="motions_per_part 5 is more than the 4 training motions"):
        load_data_recipe(_write(tmp_path, four.replace("motions_per_part = 2", "motions_per_part = 5")))
    with pytest.raises(ValueError, match="motions_per_part must be an integer >= 1"):
        load_data_recipe(_write(tmp_path, four.replace("motions_per_part = 2", "motions_per_part = 0")))


CHARLESTON = "assets/data/motions/cmu_93_03_charleston.bvh"  # shipped mocap: 353 frames at 120 Hz


def test_a_bvh_motion_is_named_from_the_repository_root(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the recipe's parts do not depend on the working directory
    held_out_bvh = BASE.replace('motions = ["squat"]', f'motions = ["{CHARLESTON}"]')
    _, _, recipe = load_data_recipe(_write(tmp_path, held_out_bvh))
    parts = {p.folder: p.config for p in recipe.parts()}
    shipped = str(ROOT / CHARLESTON)
    assert parts["holdout/shirt-default-motions"].motions == (shipped,)
    assert parts["holdout/pants-default"].motions == ("walk", shipped)
    assert all(c.motions == ("walk", "run") for f, c in parts.items() if f.startswith("train/"))
    assert motion_label(shipped) == "cmu_93_03_charleston"  # its folders' name, wherever the checkout is
    motion = load_motion(shipped, default_body())
    assert isinstance(motion, Motion) and motion.poses.shape == (353, 24, 3) and motion.trans.shape == (353, 3)
    assert motion.fps == pytest.approx(1 / 0.0083333)


@pytest.mark.parametrize("change, message", [
    (("garments = [\"shirt\", \"skirt\"]", "garments = []"), "garments must be a non-empty list"),
    (("frames = 3", "frames = 0"), "frames must be an integer >= 1"),
    (("frames = 3", "frame = 3"), "unknown field(s) frame"),
    (("garments = [\"pants\"]", "garments = [\"skirt\"]"), "holdout garments ['skirt'] are also trained on"),
    (("bodies = [\"tall\"]", "bodies = [\"short\"]"), "holdout bodies ['short'] are not among the bodies"),
    (("betas = [0.5, 0.9, 0.5]", "betas = [\"x\"]"), "betas must be a list of numbers"),
    (("name = \"tall\"", "name = \"../up\""), "name"),
])
def test_bad_tables_are_refused_naming_the_file(tmp_path, change, message):
    path = _write(tmp_path, BASE.replace(*change))
    with pytest.raises(ValueError) as error:
        load_data_recipe(path)
    assert str(path) in str(error.value) and message in str(error.value)


def test_unreadable_and_unknown_recipes(tmp_path):
    with pytest.raises(ValueError, match="not a TOML recipe"):
        read_recipe(_write(tmp_path, "[data\n"))
    with pytest.raises(FileNotFoundError, match="no recipe named 'nonesuch'"):
        read_recipe("nonesuch")
    with pytest.raises(ValueError, match="--recipe"):
        read_recipe("..")


def test_a_folder_of_another_recipe_is_refused_before_building(tmp_path):
    out = tmp_path / "data"
    other = _write(tmp_path, BASE.replace("frames = 3", "frames = 2"))
    _, table, _ = load_data_recipe(other)
    out.mkdir()
    (out / "recipe.json").write_text('{"recipe": "r", "data": {}, "data_digest": "%s", "parts": {}}'
                                     % table_digest({}))
    with pytest.raises(ValueError, match=r"recipe.json: .*other settings or inputs \(data: \{\} -> \{"):
        build_recipe(other, out)
    assert sorted(p.name for p in out.iterdir()) == ["recipe.json"]
