"""`python -m assets.motion`: preview and convert on real files; bad input gets `error:` and exit 2
and leaves earlier output alone."""

import subprocess
import sys

import numpy as np
from PIL import Image

from assets.motion import Motion
from assets.motion.__main__ import main
from tests.assets.test_motion_amass import amass_file


def test_convert_amass_then_preview_it(tmp_path):
    amass_file(tmp_path / "seq.npz", frames=6, width=156, fps_key="mocap_frame_rate")
    assert main(["convert", str(tmp_path / "seq.npz"), "--fps", "120", "--out", str(tmp_path / "m.npz")]) == 0
    motion = Motion.load(tmp_path / "m.npz")
    assert motion.fps == 120.0 and motion.num_frames == 11 and motion.shape_space == "smplh"
    out = tmp_path / "preview"
    assert main(["preview", str(tmp_path / "m.npz"), "--out", str(out), "--frames", "3", "--meshes", "ply",
                 "--transition-seconds", "0.05"]) == 0
    png = Image.open(out / "preview.png")
    assert png.size[0] > 300 and np.asarray(png.convert("L")).std() > 10  # something was drawn
    sequence = np.load(out / "body_sequence.npz")
    assert sequence["vertices"].shape == (11 + 6, 13348, 3) and sequence["vertices"].dtype == np.float32
    assert len(list((out / "meshes").glob("frame_*.ply"))) == 17


def test_bad_input_is_reported_and_keeps_earlier_output(tmp_path, capsys):
    target = tmp_path / "m.npz"
    target.write_bytes(b"earlier output")
    (tmp_path / "bad.npz").write_bytes(b"junk")
    assert main(["convert", str(tmp_path / "bad.npz"), "--out", str(target)]) == 2
    assert "error: " in capsys.readouterr().err
    assert target.read_bytes() == b"earlier output"
    assert main(["preview", "no_such_motion", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert "unknown motion 'no_such_motion'" in err and "walk" in err
    assert main(["preview", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "p")]) == 2
    assert "missing.npz" in capsys.readouterr().err


def test_module_runs_as_a_program():
    out = subprocess.run([sys.executable, "-m", "assets.motion", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "preview" in out.stdout and "convert" in out.stdout
