"""`factory.merge`: dataset folders merged into one that the networks read as one."""

import json
import shutil

import cv2
import numpy as np
import pytest

from assets.fileio import load_json, save_json, save_npz
from assets.pattern import PatternSpec
from factory.dataset import main
from factory.merge import Source, merge
from networks.data import RenderedDataset
from tests.networks.test_evaluate import write_factory_dataset

SPEC = PatternSpec(rows=4, cols=4)


def _dataset(folder, splits, motion):
    write_factory_dataset(folder, SPEC, splits, motion=motion)
    layout = {"spec": SPEC.to_dict(), "panels": []}
    save_npz(folder / "template.npz", {"layout_json": np.frombuffer(json.dumps(layout).encode(), np.uint8)})
    return folder


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    root = tmp_path_factory.mktemp("merge")
    held = _dataset(root / "held", {"train": 1, "val": 1, "test": 1}, "synth")
    more = _dataset(root / "more", {"train": 1, "test": 1}, "extra")
    shutil.copy2(held / "template.npz", more / "template.npz")  # the same garment
    return held, more


def _manifest(folder):
    return {e["name"]: e for e in map(json.loads, (folder / "manifest.jsonl").read_text().splitlines())}


def test_merged_images_keep_their_files_and_the_train_source_trains(sources, tmp_path):
    held, more = sources
    out = tmp_path / "all"
    assert main(["merge", str(held), "--train", str(more), "--out", str(out), "--no-progress"]) == 0
    merged, before, extra = _manifest(out), _manifest(held), _manifest(more)
    assert set(merged) == set(before) | set(extra)
    for name, entry in before.items():
        assert merged[name] == entry  # splits kept
    assert {merged[name]["split"] for name in extra} == {"train"}
    for name, entry in merged.items():
        source = held if name in before else more
        for field in ("image", "gt", "samples"):
            assert (out / entry[field]).read_bytes() == (source / entry[field]).read_bytes()
    splits = load_json(out / "splits.json")
    assert sorted(splits["train"]) == sorted(f"{e['motion']}/{e['frame']}" for e in merged.values()
                                             if e["split"] == "train")
    assert [s["train"] for s in load_json(out / "config.json")["merged"]] == [False, True]
    trained = RenderedDataset(out, "train", "localizer", spec=SPEC)
    assert len(trained) == 1 + len(extra)
    assert trained[len(trained) - 1]["image"].shape[-2:] == (128, 128)
    manifest = (out / "manifest.jsonl").read_bytes()
    merge(out, [Source(held), Source(more, train=True)], progress=False)  # again: nothing changes
    assert (out / "manifest.jsonl").read_bytes() == manifest
    with pytest.raises(ValueError, match=r"config.json: .*other settings or inputs \(merged: \[\{"):
        merge(out, [Source(held)], progress=False)
    assert (out / "manifest.jsonl").read_bytes() == manifest


def test_images_of_the_same_name_with_other_pixels_are_renamed_with_their_files(sources, tmp_path):
    """Two builds of the same motion and frames (other seeds) name their images alike: the later
    source's images are renamed with their files, and the merged set reads both."""
    held, more = sources
    twin = shutil.copytree(more, tmp_path / "twin")
    for entry in _manifest(twin).values():  # other pixels under the same names
        image = cv2.imread(str(twin / entry["image"]))
        cv2.imwrite(str(twin / entry["image"]), 255 - image)
    out = tmp_path / "both"
    merge(out, [Source(held), Source(more, train=True), Source(twin, train=True)], progress=False)
    merged, extra = _manifest(out), _manifest(more)
    assert set(merged) == set(_manifest(held)) | set(extra) | {f"{name}_m3" for name in extra}
    for name, entry in extra.items():
        renamed = merged[f"{name}_m3"]
        assert renamed["source_name"] == name and "source_name" not in merged[name]
        for field in ("image", "gt", "samples"):
            assert renamed[field] == entry[field].replace(name, f"{name}_m3")
            assert (out / renamed[field]).read_bytes() == (twin / entry[field]).read_bytes()
            assert (out / merged[name][field]).read_bytes() == (more / entry[field]).read_bytes()
    trained = RenderedDataset(out, "train", "localizer", spec=SPEC)
    assert len(trained) == 1 + 2 * len(extra)
    merge(out, [Source(held), Source(more, train=True), Source(twin, train=True)], progress=False)  # a rerun
    assert _manifest(out) == merged


def test_merging_what_does_not_belong_together_is_refused(sources, tmp_path):
    held, more = sources
    with pytest.raises(ValueError, match="is in both .* with the same pixels"):
        merge(tmp_path / "twice", [Source(held), Source(held, train=True)], progress=False)
    other = shutil.copytree(more, tmp_path / "other")
    save_npz(other / "template.npz", {"layout_json": np.frombuffer(b"{}", np.uint8)})
    with pytest.raises(ValueError, match="template.npz differs"):
        merge(tmp_path / "garments", [Source(held), Source(other)], progress=False)
    leak = shutil.copytree(more, tmp_path / "leak")
    test_frame = next(e for e in _manifest(held).values() if e["split"] == "test")
    meta = sorted((leak / "meta").glob("*.json"))[0]
    save_json(meta, {**load_json(meta), "motion": test_frame["motion"], "frame": test_frame["frame"]})
    with pytest.raises(ValueError, match=f"{test_frame['motion']}/{test_frame['frame']} is test"):
        merge(tmp_path / "leaky", [Source(held), Source(leak, train=True)], progress=False)
    assert not (tmp_path / "leaky").exists()  # refused before anything is written
    with pytest.raises(ValueError, match="not a factory dataset"):
        merge(tmp_path / "none", [Source(tmp_path)], progress=False)


def test_the_same_frame_of_another_simulation_may_be_in_another_split(sources, tmp_path):
    """The frame check compares simulations by their records' key: the same motion and frame of
    another simulation (another seed) may be trained on beside a held-out one; of the same
    simulation, or of a record without a key (a build before records had one), it may not."""
    held, more = sources
    test_frame = next(e for e in _manifest(held).values() if e["split"] == "test")

    def keyed(folder, key, frame=None):
        for meta in (folder / "meta").glob("*.json"):
            record = {**load_json(meta), "simulation": key}
            save_json(meta, {**record, "motion": test_frame["motion"], "frame": test_frame["frame"]}
                      if frame and record["name"] == frame else record)
        return folder

    first = keyed(shutil.copytree(held, tmp_path / "first"), "a")
    name = sorted(p.stem for p in (more / "meta").glob("*.json"))[0]
    other = keyed(shutil.copytree(more, tmp_path / "other"), "b", frame=name)
    merged = _manifest(merge(tmp_path / "two", [Source(first), Source(other, train=True)], progress=False).parent)
    frame = f"{test_frame['motion']}/{test_frame['frame']}"
    assert merged[name]["split"] == "train" and merged[test_frame["name"]]["split"] == "test"
    splits = load_json(tmp_path / "two" / "splits.json")
    assert frame in splits["train"] and frame in splits["test"]
    same = keyed(shutil.copytree(more, tmp_path / "same"), "a", frame=name)
    with pytest.raises(ValueError, match=f"{frame} is test .*both of simulation a"):
        merge(tmp_path / "one", [Source(first), Source(same, train=True)], progress=False)
    unkeyed = shutil.copytree(more, tmp_path / "unkeyed")
    meta = unkeyed / "meta" / f"{name}.json"
    save_json(meta, {**load_json(meta), "motion": test_frame["motion"], "frame": test_frame["frame"]})
    with pytest.raises(ValueError, match="without a simulation key"):
        merge(tmp_path / "old", [Source(first), Source(unkeyed, train=True)], progress=False)
