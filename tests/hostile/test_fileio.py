"""The shared guards of `assets.fileio`: names that become paths, staged outputs, a full disk, limits."""

from __future__ import annotations

import errno
import pytest

from assets.fileio import atomic_path, check_limit, copy_file, file_digest, safe_name, staged_outputs


@pytest.mark.hostile("outside")
@pytest.mark.parametrize("name", ["../x", "a/b", "a\\b", "..", ".", "", ".hidden", "tab\there", "nl\n",
                                  "x" * 201, None, 3])
def test_safe_name_refuses_what_is_not_one_path_component(name):
    with pytest.raises(ValueError, match="pattern.json: .*name"):
        safe_name(name, "pattern.json: field name")


@pytest.mark.hostile("outside")
@pytest.mark.parametrize("name", ["shirt", "cam_01", "Ärmel links", "front-panel.v2"])
def test_safe_name_keeps_ordinary_names(name):
    assert safe_name(name, "x") == name


@pytest.mark.hostile("half")
def test_staged_outputs_replace_together_or_not_at_all(tmp_path):
    (tmp_path / "a.txt").write_text("old a")
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(RuntimeError):
        with staged_outputs(tmp_path) as stage:
            (stage / "a.txt").write_text("new a")
            (stage / "sub").mkdir()
            (stage / "sub" / "b.txt").write_text("new b")
            raise RuntimeError("found late")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "keep.txt"]
    assert (tmp_path / "a.txt").read_text() == "old a"
    with staged_outputs(tmp_path) as stage:
        (stage / "a.txt").write_text("new a")
        (stage / "sub").mkdir()
        (stage / "sub" / "b.txt").write_text("new b")
    assert (tmp_path / "a.txt").read_text() == "new a"
    assert (tmp_path / "sub" / "b.txt").read_text() == "new b"
    assert (tmp_path / "keep.txt").read_text() == "mine"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.hostile("half")
def test_a_full_disk_names_the_file_and_keeps_the_old_one(tmp_path):
    target = tmp_path / "sequence.npz"
    target.write_bytes(b"good")
    with pytest.raises(OSError, match="sequence.npz: disk full"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert target.read_bytes() == b"good"
    assert [p.name for p in tmp_path.iterdir()] == ["sequence.npz"]


@pytest.mark.hostile("stale")
def test_copy_file_and_digest(tmp_path):
    (tmp_path / "a").write_bytes(b"x" * 3_000_000)
    copy_file(tmp_path / "a", tmp_path / "b")
    assert file_digest(tmp_path / "a") == file_digest(tmp_path / "b")
    (tmp_path / "b").write_bytes(b"y")
    assert file_digest(tmp_path / "a") != file_digest(tmp_path / "b")


@pytest.mark.hostile("memory")
def test_check_limit_names_the_option():
    check_limit(10, 10, "frames", "walk.npz", "--max-frames")
    with pytest.raises(ValueError, match=r"walk.npz: frames is 11.*--max-frames"):
        check_limit(11, 10, "frames", "walk.npz", "--max-frames")
    with pytest.raises(ValueError, match="nan"):
        check_limit(float("nan"), 10, "frames", "walk.npz", "--max-frames")


@pytest.mark.hostile("half")
@pytest.mark.parametrize("blocker", ["dir_for_file", "file_for_dir"])
def test_staged_outputs_refuse_before_moving_when_a_target_is_blocked(tmp_path, blocker):
    """A folder where an output file goes (or a file where its folder goes) is found before the first
    file moves, so the old outputs stay whole."""
    (tmp_path / "a.txt").write_text("old a")
    if blocker == "dir_for_file":
        (tmp_path / "b.txt").mkdir()
    else:
        (tmp_path / "sub").write_text("a file")
    with pytest.raises(OSError, match="in the way"):
        with staged_outputs(tmp_path) as stage:
            (stage / "a.txt").write_text("new a")
            (stage / "b.txt").write_text("new b")
            (stage / "sub").mkdir()
            (stage / "sub" / "c.txt").write_text("new c")
    assert (tmp_path / "a.txt").read_text() == "old a"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
