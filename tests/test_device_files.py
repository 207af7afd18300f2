"""benchmarks/device_files.py: folders moved in checked parts to and from the device machine."""

import json
import os

import pytest

from benchmarks.device_files import MANIFEST, main, pack, send, unpack


@pytest.fixture
def source(tmp_path):
    src = tmp_path / "weights"
    (src / "sub").mkdir(parents=True)
    files = {"localizer.pt": os.urandom(300_000), "sub/crosspoints.pt": os.urandom(1_100_000), "empty.txt": b""}
    for name, data in files.items():
        (src / name).write_bytes(data)
    return src, files


def test_parts_sent_in_several_calls_unpack_to_the_same_files(source, tmp_path):
    src, files = source
    manifest = pack(src, tmp_path / "parts", part_mb=0.25)
    sizes = [p["bytes"] for p in manifest["parts"]]
    assert len(sizes) == 6 and max(sizes) == 262_144 and sum(sizes) == 1_400_000  # files cross part borders
    fetched = tmp_path / "fetched"  # as the calls' files are gathered here: two calls, then the rest
    assert main(["send", str(tmp_path / "parts"), str(fetched), "--parts", "0-1,3"]) == 0
    with pytest.raises(ValueError, match="part.002 is missing; part.004 is missing; part.005 is missing"):
        unpack(fetched, tmp_path / "out")
    assert not (tmp_path / "out").exists()  # nothing written from incomplete parts
    send(tmp_path / "parts", fetched, "2,4-5")
    written = unpack(fetched, tmp_path / "out")
    assert sorted(p.relative_to(tmp_path / "out").as_posix() for p in written) == sorted(files)
    for name, data in files.items():
        assert (tmp_path / "out" / name).read_bytes() == data


def test_damaged_parts_and_bad_requests_are_refused(source, tmp_path, capsys):
    src, _ = source
    pack(src, tmp_path / "parts", part_mb=0.5)
    part = tmp_path / "parts" / "part.001"
    original = part.read_bytes()
    data = bytearray(original)
    data[10] ^= 1
    part.write_bytes(bytes(data))
    assert main(["unpack", str(tmp_path / "parts"), str(tmp_path / "out")]) == 2
    assert "part.001 is damaged" in capsys.readouterr().err
    with pytest.raises(ValueError, match="there are 3 parts"):
        send(tmp_path / "parts", tmp_path / "to", "2-3")
    with pytest.raises(ValueError, match="no MANIFEST.json"):
        unpack(tmp_path, tmp_path / "out")
    part.write_bytes(original)
    manifest = json.loads((tmp_path / "parts" / MANIFEST).read_text())
    manifest["files"][0]["path"] = "../escape.pt"
    (tmp_path / "parts" / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="outside the destination"):
        unpack(tmp_path / "parts", tmp_path / "out")
    assert main(["wait", str(tmp_path / "never"), "--timeout", "0"]) == 1
    assert main(["wait", str(part), "--timeout", "0"]) == 0
