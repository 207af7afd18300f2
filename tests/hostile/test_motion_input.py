"""Hostile and careless motion input: frame rates and frame counts that ask for gigabytes, NaN that
would give an all-NaN body, files that ended in a traceback, and a preview whose outputs a full disk
left mixed from two runs."""

from __future__ import annotations

import errno
import io
import zipfile

import numpy as np
import pytest

from assets.body import default_body
from assets.fileio import atomic_path
from assets.motion import Motion, resample
from assets.motion.bvh import parse_bvh
from assets.motion.sources import load_motion
from tests.hostile.conftest import assert_refused, files_under, run_cli


def _amass(path, frames=3, fps=60.0, **extra):
    rng = np.random.default_rng(1)
    data = {"poses": rng.normal(0.0, 0.3, (frames, 72)), "trans": rng.normal(0.0, 0.5, (frames, 3)),
            "betas": rng.normal(0.0, 1.0, 10), "gender": np.array("female"), "mocap_framerate": np.array(fps)}
    data.update(extra)
    np.savez(path, **{k: v for k, v in data.items() if v is not None})
    return path


def _bvh(path, rows: list[str], frames: int | None = None, frame_time: str = "0.0333") -> None:
    """A two-joint BVH (root with six channels, one child with three) and the given frame lines."""
    path.write_text(
        "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
        "Yrotation\n JOINT Leg\n {\n  OFFSET 0 -1 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n"
        f"   OFFSET 0 -1 0\n  }}\n }}\n}}\nMOTION\nFrames: {len(rows) if frames is None else frames}\n"
        f"Frame Time: {frame_time}\n" + "".join(row + "\n" for row in rows))


@pytest.mark.hostile("memory")
def test_amass_at_a_thousandth_of_a_hertz_is_refused(tmp_path):
    # Three frames 1000 s apart, resampled to 120 Hz, were a quarter of a million posed bodies.
    path = _amass(tmp_path / "slow.npz", fps=0.001)
    result = run_cli("assets.motion", "preview", path, "--out", tmp_path / "out", mem_gib=4.0, timeout=120)
    assert_refused(result, "slow.npz: mocap_framerate: frame rate 0.001 Hz is outside 1 to 1000 Hz")
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


@pytest.mark.hostile("memory")
def test_resampling_beyond_max_frames_is_refused_before_allocation():
    motion = Motion(poses=np.zeros((3, 24, 3)), trans=np.zeros((3, 3)), fps=1.0, name="slow")
    with pytest.raises(ValueError, match="the frame count is 2,001, above the limit of 100; raise it with --max-frames"):
        resample(motion, 1000.0, max_frames=100)
    assert resample(motion, 1000.0, max_frames=3000).num_frames == 2001


def _npy_header_only(shape: tuple[int, ...]) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buffer.getvalue()


@pytest.mark.hostile("memory")
@pytest.mark.parametrize("kind", ["amass", "saved"])
def test_npz_declaring_a_billion_frames_is_refused_before_decompression(tmp_path, kind):
    path = tmp_path / f"{kind}.npz"
    _amass(path) if kind == "amass" else Motion(poses=np.zeros((2, 24, 3)), trans=np.zeros((2, 3)), fps=30.0).save(path)
    with zipfile.ZipFile(path) as archive:
        members = {n: archive.read(n) for n in archive.namelist()}
    members["poses.npy"] = _npy_header_only((10**9, 72) if kind == "amass" else (10**9, 24, 3))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, raw in members.items():
            archive.writestr(name, raw)
    result = run_cli("assets.motion", "convert", path, "--out", tmp_path / "m.npz", mem_gib=3.0, timeout=120)
    assert_refused(result, f"{kind}.npz: poses: the frame count is 1e+09", "--max-frames")


@pytest.mark.hostile("silent")
@pytest.mark.parametrize("field", ["betas", "trans"])
def test_amass_with_nan_is_refused_naming_the_field(tmp_path, field):
    values = {"betas": np.full(10, np.nan), "trans": np.full((3, 3), np.nan)}
    path = _amass(tmp_path / "nan.npz", **{field: values[field]})
    with pytest.raises(ValueError, match=rf"nan\.npz: {field} holds NaN"):
        load_motion(path)


@pytest.mark.hostile("silent")
def test_saved_motion_with_nan_betas_is_refused(tmp_path):
    Motion(poses=np.zeros((2, 24, 3)), trans=np.zeros((2, 3)), fps=30.0).save(tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz") as data:
        arrays = dict(data)
    np.savez(tmp_path / "m.npz", **dict(arrays, betas=np.array([np.nan, 1.0])))
    with pytest.raises(ValueError, match=r"m\.npz: motion.*betas holds NaN"):
        Motion.load(tmp_path / "m.npz")


@pytest.mark.hostile("silent")
def test_bvh_with_nan_channels_is_refused(tmp_path):
    _bvh(tmp_path / "nan.bvh", ["0 0 0 0 0 0 0 0 0", "0 0 0 0 nan 0 0 0 0"])
    with pytest.raises(ValueError, match=r"nan\.bvh: motion data holds NaN"):
        parse_bvh(tmp_path / "nan.bvh")


@pytest.mark.hostile("silent")
def test_nan_betas_are_refused_by_the_body():
    with pytest.raises(ValueError, match="betas must be finite numbers"):
        default_body().rest(np.array([np.nan] * default_body().num_betas))


def _bad_motion_inputs(tmp_path):
    """name -> (the file, the text the error must hold)."""
    cases = {}
    (tmp_path / "empty.npz").write_bytes(b"")
    cases["empty_npz"] = (tmp_path / "empty.npz", "not a readable .npz")
    cases["poses_of_text"] = (_amass(tmp_path / "text.npz", poses=np.full((3, 72), "x")), "poses must be")
    cases["gender_empty"] = (_amass(tmp_path / "gender.npz", gender=np.array([], dtype="U1")), None)
    cases["fps_of_text"] = (_amass(tmp_path / "fps.npz", mocap_framerate=np.array("fast")), "mocap_framerate must be one number")
    Motion(poses=np.zeros((2, 24, 3)), trans=np.zeros((2, 3)), fps=30.0).save(tmp_path / "meta.npz")
    with np.load(tmp_path / "meta.npz") as data:
        np.savez(tmp_path / "meta.npz", **dict(data, meta=np.array("[1, 2]")))
    cases["meta_not_object"] = (tmp_path / "meta.npz", "meta.npz")
    _bvh(tmp_path / "truncated.bvh", ["0 0 0 0 0 0 0 0 0"], frames=3)
    cases["bvh_truncated"] = (tmp_path / "truncated.bvh", "'Frames: 3' but 1 frame lines follow")
    _bvh(tmp_path / "words.bvh", ["0 0 0 0 0 0 0 0 zero"])
    cases["bvh_not_numbers"] = (tmp_path / "words.bvh", "motion data")
    deep = "HIERARCHY\nROOT j0\n{\n OFFSET 0 0 0\n" + "".join(f"JOINT j{i}\n{{\nOFFSET 0 1 0\n" for i in range(1, 3000))
    (tmp_path / "deep.bvh").write_text(deep + "}\n" * 3000 + "MOTION\nFrames: 1\nFrame Time: 0.01\n\n")
    cases["bvh_deep"] = (tmp_path / "deep.bvh", "more than 500 joints")
    _bvh(tmp_path / "slow.bvh", ["0 0 0 0 0 0 0 0 0", "0 0 0 0 0 0 0 0 0"], frame_time="1000")
    cases["bvh_slow"] = (tmp_path / "slow.bvh", "outside 1 to 1000 Hz")
    return cases


@pytest.mark.hostile("traceback")
@pytest.mark.parametrize("case", ["empty_npz", "poses_of_text", "gender_empty", "fps_of_text", "meta_not_object",
                                  "bvh_truncated", "bvh_not_numbers", "bvh_deep", "bvh_slow"])
def test_careless_motion_files_are_refused_naming_the_file(tmp_path, case):
    path, needle = _bad_motion_inputs(tmp_path)[case]
    if case == "gender_empty":  # an empty gender means the neutral one, not a crash
        assert load_motion(path).gender == "neutral"
        return
    with pytest.raises(ValueError) as caught:
        load_motion(path)
    assert str(path) in str(caught.value) and needle in str(caught.value), caught.value


def _preview(out, *extra):
    from assets.motion.__main__ import main

    return main(["preview", "tpose", "--seconds", "0.1", "--fps", "30", "--transition", "none", "--frames", "2",
                 "--out", str(out), *extra])


@pytest.mark.hostile("half")
def test_preview_on_a_full_disk_leaves_the_earlier_outputs_whole(tmp_path, monkeypatch, capsys):
    import assets.motion.__main__ as cli

    out = tmp_path / "out"
    assert _preview(out, "--meshes", "obj") == 0
    before = files_under(out)
    assert {"motion.npz", "body_sequence.npz", "preview.png", "summary.json", "meshes/frame_0000.obj"} <= set(before)

    def full_disk(path, obj):
        with atomic_path(path) as tmp:
            tmp.write_text("{")
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(cli, "save_json", full_disk)
    capsys.readouterr()
    assert _preview(out, "--meshes", "obj", "--seconds", "0.2") == 2
    assert "summary.json: disk full" in capsys.readouterr().err
    assert files_under(out) == before


@pytest.mark.hostile("half")
def test_preview_refuses_bad_arguments_before_writing(tmp_path):
    out = tmp_path / "out"
    assert _preview(out) == 0
    before = files_under(out)
    assert _preview(out, "--frames", "0") == 2
    assert _preview(out, "--transition", "A", "--transition-seconds", "nan") == 2
    assert files_under(out) == before


@pytest.mark.hostile("outside")
@pytest.mark.parametrize("spec, label", [("walk", "walk"), ("/data/CMU_01_01_poses.npz", "CMU_01_01_poses"),
                                         ("clips/dance.BVH", "dance"), ("../../x", None), ("/data/.npz", None),
                                         ("a/b", None)])
def test_a_motion_goes_by_a_label_that_is_one_path_component(spec, label):
    from assets.motion.sources import motion_label

    if label is None:
        with pytest.raises(ValueError, match="cannot be a file name"):
            motion_label(spec)
    else:
        assert motion_label(spec) == label


@pytest.mark.hostile("outside")
def test_two_motion_files_of_one_name_cannot_share_a_dataset_folder():
    from factory.shards import motion_labels

    assert motion_labels(("walk", "/data/dance.npz")) == {"walk": "walk", "/data/dance.npz": "dance"}
    with pytest.raises(ValueError, match="share the name 'dance'"):
        motion_labels(("/a/dance.npz", "/b/dance.bvh"))
