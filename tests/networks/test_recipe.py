"""Network recipes: the shipped recipes load and round-trip, bad tables are refused naming the file,
a tiny recipe trains a few CPU steps through `networks.train --recipe` (on the synthesizer, and on a
recipe build's parts joined), and a run never starts from other data or weights than its recipe names."""

import json
from pathlib import Path

import numpy as np
import pytest

from assets.fileio import load_json, save_json, save_npz
from assets.pattern import PatternSpec
from assets.recipes import RECIPES, table_digest
from networks.checkpoint import read_checkpoint
from networks.recipe import NetworkRecipe, check_data_folder, load_recipe, stored_init
from networks.config import TrainConfig
from networks.train import main, run_marker_ids, training_spec
from networks.weights import file_sha256, read_manifest, repository_root
from tests.networks.test_evaluate import write_factory_dataset

SPEC = PatternSpec(rows=2, cols=2, num_ids=64)
SHIPPED = sorted(RECIPES.glob("*.toml"))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_shipped_recipe_loads_and_round_trips(path):
    recipe = load_recipe(path.stem)
    assert recipe.name == path.stem and recipe.networks
    for task, network in recipe.networks.items():
        again = NetworkRecipe.from_table(task, network.to_table(), "round trip")
        assert again == network
        assert network.config.task == task
    assert recipe.data_digest == table_digest(recipe.data)


#: a tiny run's settings, shared by the test recipes
SMALL = """lr = 1e-3
warmup_steps = 0
augment = false
num_workers = 0
val_samples = 2
val_every = 100
checkpoint_every = 100
"""

TINY = """
[networks.localizer]
data = "synth"
steps = 3
batch_size = 1
image_size = 64
""" + SMALL


def _recipe(tmp_path: Path, text: str, name: str = "tiny") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, problem", [
    (TINY.replace("steps = 3", "steps = 3\nlearning_rate = 1"), "unknown.*learning_rate"),
    (TINY.replace('data = "synth"', 'data = "photos"'), "data must be one of rendered, synth"),
    (TINY.replace('data = "synth"', 'data = "synth"\ninit = "runs/x.pt"'), "init must be a table of commit, file"),
    (TINY + '[networks.localizer.init]\ncommit = "abc"\nfile = "l.pt"\nsha256 = "00"\n', "40 and init.sha256 64"),
    (TINY.replace('data = "synth"', 'data = "synth"\nsynth_weight = 0.5'), "synth_weight must be 1"),
    (TINY.replace("steps = 3", "steps = -3"), "steps"),
    (TINY.replace("[networks.localizer]", "[networks.detector]"), r"\[networks.detector\] is not a network"),
    (TINY.replace('data = "synth"', 'data = "rendered"'), "no \\[data\\] table"),
    ("[data]\ngarments = ['shirt']\n", "no \\[networks.<task>\\] table"),
    (TINY + "\n[training]\nsteps = 1\n", "unknown table.*training"),
])
def test_bad_recipes_are_refused_naming_the_file(tmp_path, text, problem):
    path = _recipe(tmp_path, text)
    with pytest.raises(ValueError, match=problem) as error:
        load_recipe(path)
    assert str(path) in str(error.value)


def test_a_tiny_recipe_trains_on_the_cpu_and_records_itself(tmp_path, capsys):
    pattern = tmp_path / "pattern.json"
    SPEC.save(pattern)
    recipe = _recipe(tmp_path, TINY)
    out = tmp_path / "run"
    common = ["--recipe", str(recipe), "--out", str(out), "--pattern", str(pattern), "--device", "cpu", "--no-progress"]
    assert main(common + ["--until-step", "2"]) == 0
    assert "localizer: stopped (continue with --resume) at step 2 of 3" in capsys.readouterr().out
    record = load_json(out / "recipe.json")
    assert record["recipe"] == "tiny" and record["task"] == "localizer" and record["changed"] == {}
    assert read_checkpoint(out / "last.pt")["config"]["image_size"] == 64  # the recipe's, not the default
    assert main(common + ["--resume"]) == 0
    assert "finished at step 3 of 3" in capsys.readouterr().out
    # flags still override the recipe, and the record says so
    assert main(common[:2] + ["--out", str(tmp_path / "longer"), "--steps", "1"] + common[4:]) == 0
    assert load_json(tmp_path / "longer" / "recipe.json")["changed"] == {"steps": 1}
    # a run folder of another recipe file is refused; so is data for a synthesizer recipe
    _recipe(tmp_path, TINY.replace("steps = 3", "steps = 4"), "tiny")
    assert main(common + ["--resume"]) == 2
    assert "recipe.json: " in (err := capsys.readouterr().err) and "file_sha256: " in err
    assert main(common[:2] + ["--out", str(tmp_path / "x"), "--data", str(tmp_path)] + common[4:]) == 2
    assert "trains on the synthesizer alone; leave out --data" in capsys.readouterr().err
    assert main(common[:2] + ["recognizer", "--out", str(tmp_path / "y")] + common[4:]) == 2
    assert "no [networks.recognizer] table" in capsys.readouterr().err


RENDERED = """
[data]
garments = ["a", "b"]
motions = ["walk"]

[networks.recognizer]
recognizer_classes = "codebook"
steps = 2
batch_size = 2
""" + SMALL


def _recipe_build(folder: Path, data: dict, parts: list[str]) -> Path:
    """A folder as `factory.dataset build --recipe` leaves it: recipe.json and one dataset per part."""
    for k, part in enumerate(parts):
        write_factory_dataset(folder / part, SPEC, {"train": 1, "val": 1}, seed=k)
    save_json(folder / "recipe.json", {"recipe": "r", "data": data, "data_digest": table_digest(data),
                                       "parts": {"train": parts, "holdout": []}})
    return folder


def test_a_rendered_recipe_trains_on_its_build_s_parts_joined(tmp_path, capsys):
    pattern = tmp_path / "pattern.json"
    SPEC.save(pattern)
    recipe = load_recipe(_recipe(tmp_path, RENDERED, "r"))
    built = _recipe_build(tmp_path / "data", recipe.data, ["train/a-default", "train/b-default"])
    assert check_data_folder(recipe, built) == [built / "train/a-default", built / "train/b-default"]
    out = tmp_path / "run"
    assert main(["--recipe", str(recipe.path), "--data", str(built), "--out", str(out), "--pattern", str(pattern),
                 "--device", "cpu", "--no-progress"]) == 0
    assert "recognizer: finished at step 2 of 2" in capsys.readouterr().out
    assert read_checkpoint(out / "last.pt")["data"] == f"{built / 'train/a-default'}, {built / 'train/b-default'}"
    # another [data] table, an unfinished part, no build at all: refused before training
    other = load_recipe(_recipe(tmp_path, RENDERED.replace('"walk"', '"run"'), "r"))
    with pytest.raises(ValueError, match="another \\[data\\] table"):
        check_data_folder(other, built)
    (built / "train/b-default/manifest.jsonl").unlink()
    with pytest.raises(ValueError, match="unfinished parts train/b-default"):
        check_data_folder(recipe, built)
    with pytest.raises(FileNotFoundError, match="no recipe.json; build the data with"):
        check_data_folder(recipe, tmp_path)
    assert main(["--recipe", str(recipe.path), "--out", str(tmp_path / "z"), "--device", "cpu"]) == 2
    assert "give --data" in capsys.readouterr().err


def test_a_recipe_s_init_is_pinned_stored_weights(tmp_path):
    entry = read_manifest(repository_root())["weights"]["localizer"]
    pinned = {k: entry[k] for k in ("commit", "file", "sha256")}
    network = NetworkRecipe.from_table("localizer", {"init": pinned}, "t")
    assert network.to_table()["init"] == pinned
    written = stored_init(network, "localizer", None, tmp_path / "cache")  # from the repository's history
    assert written == tmp_path / "cache" / pinned["file"] and file_sha256(written) == pinned["sha256"]
    assert stored_init(network, "localizer", written, tmp_path / "other") == written  # a carried copy is checked
    wrong = tmp_path / "localizer.pt"
    wrong.write_bytes(b"not the stored weights")
    with pytest.raises(ValueError, match="not the weights the recipe's localizer starts from"):
        stored_init(network, "localizer", wrong, tmp_path / "cache")
    with pytest.raises(FileNotFoundError, match="no such checkpoint"):
        stored_init(network, "localizer", tmp_path / "none.pt", tmp_path / "cache")
    elsewhere = NetworkRecipe.from_table("localizer", {"init": {**pinned, "sha256": "0" * 64}}, "t")
    with pytest.raises(ValueError, match="does not match the localizer init weights' SHA-256"):
        stored_init(elsewhere, "localizer", None, tmp_path / "fresh")
    fresh = NetworkRecipe.from_table("localizer", {}, "t")
    assert stored_init(fresh, "localizer", None, tmp_path / "cache") is None
    with pytest.raises(ValueError, match="starts from no stored weights; leave out --init"):
        stored_init(fresh, "localizer", wrong, tmp_path / "cache")

def write_template(folder: Path, spec: PatternSpec, panels: list[tuple[int, int, int]]) -> Path:
    """folder/template.npz with what the networks read of a garment: its layout's spec and panels of
    (first_id, rows, cols)."""
    layout = {"spec": spec.to_dict(), "panels": [{"name": f"p{k}", "spec": {**spec.to_dict(), "rows": r, "cols": c},
                                                  "first_id": first} for k, (first, r, c) in enumerate(panels)]}
    folder.mkdir(parents=True, exist_ok=True)
    save_npz(folder / "template.npz", {"layout_json": np.frombuffer(json.dumps(layout).encode(), np.uint8)})
    return folder


def test_joined_folders_share_one_pattern_and_their_garments_ids(tmp_path):
    first = write_template(tmp_path / "a", SPEC, [(0, 2, 2)])
    second = write_template(tmp_path / "b", SPEC, [(2, 1, 3), (40, 1, 1)])
    assert training_spec([first, second]) == SPEC
    ids, classes = run_marker_ids(TrainConfig("recognizer", recognizer_classes="garment"), [first, second], None)
    assert ids.tolist() == classes.tolist() == [0, 1, 2, 3, 4, 40]
    other = write_template(tmp_path / "c", PatternSpec(rows=2, cols=2, num_ids=80), [(0, 1, 1)])
    with pytest.raises(ValueError, match=f"{other}: printed with another pattern than {first}"):
        training_spec([first, other])
