"""Compact (int8) checkpoints, and the weights kept in a repository's history: store, clone, fetch."""

import json
import subprocess

import pytest
import torch

from assets.pattern import PatternSpec
from networks.checkpoint import load_checkpoint, read_checkpoint, save_checkpoint, slim_checkpoint
from networks.config import TrainConfig
from networks.models import normalize
from networks.tasks import build_model
from networks.weights import MANIFEST, fetch, read_manifest, store
from networks.weights import main as weights_main

SPEC = PatternSpec(rows=2, cols=2, num_ids=16)


@pytest.fixture(scope="module")
def localizer(tmp_path_factory):
    """A localizer checkpoint whose batch norms hold non-trivial statistics, and its model."""
    torch.manual_seed(0)
    model = build_model("localizer", SPEC.num_ids, SPEC.crosspoints_per_side)
    with torch.no_grad():
        model.train()
        model(normalize(torch.randint(0, 256, (4, 3, 64, 64), dtype=torch.uint8)))
    path = tmp_path_factory.mktemp("loc") / "last.pt"
    save_checkpoint(path, "localizer", model, TrainConfig("localizer"), SPEC, step=7)
    return path, model.eval()


@pytest.fixture()
def repo(tmp_path, monkeypatch):
    for name in ("AUTHOR", "COMMITTER"):
        monkeypatch.setenv(f"GIT_{name}_NAME", "test")
        monkeypatch.setenv(f"GIT_{name}_EMAIL", "test@example.invalid")
    root = tmp_path / "repo"
    (root / "networks").mkdir(parents=True)
    (root / "README.md").write_text("project\n")
    for args in (["init", "-q", "-b", "main"], ["add", "README.md"], ["commit", "-q", "-m", "start"]):
        subprocess.run(["git", "-C", str(root), *args], check=True)
    return root


def _git(root, *args):
    return subprocess.run(["git", "-C", str(root), *args], check=True, capture_output=True, text=True).stdout


def test_int8_checkpoint_is_about_half_of_bf16_and_computes_the_same(localizer, tmp_path):
    path, model = localizer
    compact = slim_checkpoint(path, tmp_path / "loc8.pt", dtype=torch.int8)
    bf16 = slim_checkpoint(path, tmp_path / "loc16.pt")
    # half, and the float32 head's 2.4 MB (0.58 here: 13.7 of 23.6 MB)
    assert compact.stat().st_size < 0.6 * bf16.stat().st_size
    raw = torch.load(compact, weights_only=True)
    assert raw["model"]["backbone.conv1.weight"].dtype == torch.int8
    assert raw["model"]["backbone.bn1.running_var"].dtype == torch.float32
    # the head that regresses the points stays float32 (FLOAT_WEIGHTS), the only weights that do
    assert {key for key, value in raw["model"].items() if value.dim() >= 2 and value.dtype == torch.float32} \
        == {"head.conv.weight", "head.out.weight"}
    assert not any(key.startswith("head.") for key in raw["int8_scales"])
    assert raw["optimizer"] is None and raw["step"] == 7
    loaded, _, record = load_checkpoint(compact, expected_task="localizer", spec=SPEC)
    # each weight within half a step of its channel's scale
    for key, value in model.state_dict().items():
        got = loaded.state_dict()[key]
        if key in raw["int8_scales"]:
            step = raw["int8_scales"][key].view(-1, *[1] * (value.dim() - 1))
            assert torch.all((got - value).abs() <= step / 2 + 1e-7), key
        else:
            assert torch.equal(got, value.float()), key
    x = normalize(torch.randint(0, 256, (2, 3, 64, 64), dtype=torch.uint8))
    with torch.no_grad():
        want, have = model(x), loaded(x)
    # an untrained ResNet's 19 layers amplify the rounding: a few percent here (trained ones: RESULTS.md)
    assert (have - want).norm() / want.norm() < 0.05
    # a slim copy of a compact checkpoint is an ordinary bf16 one
    again = read_checkpoint(slim_checkpoint(compact, tmp_path / "again.pt"))
    assert not again["int8_scales"] and again["model"]["backbone.conv1.weight"].dtype == torch.bfloat16


def test_scale_that_fits_no_weight_is_refused(localizer, tmp_path):
    compact = slim_checkpoint(localizer[0], tmp_path / "loc8.pt", dtype=torch.int8)
    raw = torch.load(compact, weights_only=True)
    raw["int8_scales"]["backbone.conv1.weight"] = torch.ones(3)
    torch.save(raw, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match=r"bad\.pt: int8_scales\['backbone\.conv1\.weight'\] fits no int8 weight"):
        read_checkpoint(tmp_path / "bad.pt")


def test_store_keeps_weights_out_of_the_tree_and_a_clone_fetches_them(localizer, repo, tmp_path):
    folder = tmp_path / "store"
    slim_checkpoint(localizer[0], folder / "localizer.pt", dtype=torch.int8)
    # the run's record of a recipe (networks.train --recipe) names the recipe and its data in the entry
    made = {"recipe": "r", "file_sha256": "a" * 64, "data_digest": "b" * 64, "task": "localizer", "network": {}}
    (folder / "localizer.recipe.json").write_text(json.dumps(made))
    before = _git(repo, "rev-parse", "HEAD").strip()
    manifest = store(folder, root=repo, source="a test")
    entry = manifest["weights"]["localizer"]
    assert entry["int8"] and entry["step"] == 7 and entry["source"] == "a test"
    assert entry["recipe"] == {"recipe": "r", "file_sha256": "a" * 64, "data_digest": "b" * 64}
    # HEAD: a merge of the old HEAD and the orphan commit, whose tree is the old one plus the manifest
    parents = _git(repo, "rev-list", "--parents", "-n", "1", "HEAD").split()[1:]
    assert parents == [before, entry["commit"]]
    assert _git(repo, "ls-tree", "-r", "--name-only", "HEAD").split() == ["README.md", MANIFEST.as_posix()]
    assert _git(repo, "ls-tree", "--name-only", entry["commit"]).split() == ["localizer.pt"]
    assert _git(repo, "rev-list", "--parents", "-n", "1", entry["commit"]).split() == [entry["commit"]]
    assert not _git(repo, "status", "--porcelain")
    assert json.loads((repo / MANIFEST).read_text()) == manifest == read_manifest(repo)

    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(repo), str(clone)], check=True)
    written = fetch(tmp_path / "weights", root=clone, names=("localizer",))
    assert written["localizer"].read_bytes() == (folder / "localizer.pt").read_bytes()
    load_checkpoint(written["localizer"], expected_task="localizer", spec=SPEC)
    assert set(fetch(tmp_path / "weights", root=clone)) == {"localizer"}  # by default all that is stored
    with pytest.raises(ValueError, match="no stored weights for recognizer"):
        fetch(tmp_path / "weights", root=clone, names=("localizer", "recognizer"))

    shallow = tmp_path / "shallow"
    subprocess.run(["git", "clone", "-q", "--depth", "1", f"file://{repo}", str(shallow)], check=True)
    with pytest.raises(ValueError, match="lacks commit .* holding the localizer weights .*shallow clone"):
        fetch(tmp_path / "w2", root=shallow, names=("localizer",))


def test_store_refuses_bad_input_and_leaves_head(localizer, repo, tmp_path):
    before = _git(repo, "rev-parse", "HEAD")
    with pytest.raises(ValueError, match="holds none of localizer.pt"):
        store(tmp_path, root=repo)
    wrong = tmp_path / "wrong"
    slim_checkpoint(localizer[0], wrong / "recognizer.pt", dtype=torch.int8)
    with pytest.raises(ValueError, match=r"recognizer\.pt: a localizer checkpoint under the name recognizer\.pt"):
        store(wrong, root=repo)
    classifier = build_model("recognizer", SPEC.num_ids, SPEC.crosspoints_per_side)
    mislabeled = tmp_path / "mislabeled"
    save_checkpoint(mislabeled / "reader.pt", "recognizer", classifier, TrainConfig("recognizer"), SPEC, step=1)
    with pytest.raises(ValueError, match=r"reader\.pt: an ID classifier under the name reader\.pt"):
        store(mislabeled, root=repo)
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "crosspoints.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match=r"crosspoints\.pt: not a checkpoint"):
        store(junk, root=repo)
    other = tmp_path / "other"
    slim_checkpoint(localizer[0], other / "localizer.pt", dtype=torch.int8)
    (other / "localizer.recipe.json").write_text(json.dumps({"recipe": "r", "task": "recognizer"}))
    with pytest.raises(ValueError, match=r"localizer\.recipe\.json: not the recipe\.json of a localizer run"):
        store(other, root=repo)
    good = tmp_path / "good"
    slim_checkpoint(localizer[0], good / "localizer.pt", dtype=torch.int8)
    (repo / "other.txt").write_text("staged\n")
    _git(repo, "add", "other.txt")
    with pytest.raises(ValueError, match="staged changes"):
        store(good, root=repo)
    assert _git(repo, "rev-parse", "HEAD") == before and not (repo / MANIFEST).exists()


def test_cli_store_list_fetch(localizer, repo, tmp_path, capsys):
    folder = tmp_path / "store"
    slim_checkpoint(localizer[0], folder / "localizer.pt", dtype=torch.int8)
    at = ["--repo", str(repo)]
    assert weights_main([*at, "store", str(folder), "--source", "cli"]) == 0
    assert weights_main([*at, "list"]) == 0
    assert '"source": "cli"' in capsys.readouterr().out
    assert weights_main([*at, "fetch", "--out", str(tmp_path / "w"), "--networks", "localizer"]) == 0
    assert (tmp_path / "w" / "localizer.pt").is_file()
    assert weights_main([*at, "fetch", "--out", str(tmp_path / "w"), "--networks", "reader,crosspoints"]) == 2
    assert "no stored weights for reader, crosspoints" in capsys.readouterr().err
    (repo / MANIFEST).write_text("{")
    assert weights_main([*at, "list"]) == 2
    assert "weights.json: not JSON" in capsys.readouterr().err
