"""benchmarks/device_factory.py: the factory's Python, packages and Blender relocated to the GPU machine."""

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from benchmarks.device_factory import (FACTORY_DISTRIBUTIONS, LEFT_OUT, MANIFEST, PYTHON, carry_groups,
                                       distributions, pack, python_entries, site_entries, unpack)

ROOT = Path(__file__).resolve().parents[1]


def _names(dists):
    return {d.metadata["Name"].lower().replace("_", "-") for d in dists}


def test_every_project_dependency_is_carried_or_left_out_on_purpose():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    required = project["dependencies"] + project["optional-dependencies"]["factory"]
    names = {r.split(";")[0].split("[")[0].split("<")[0].split(">")[0].split("=")[0].strip().lower() for r in required}
    decided = {n.lower() for n in FACTORY_DISTRIBUTIONS + LEFT_OUT}
    assert names <= decided, f"decide whether the factory on the GPU machine needs {sorted(names - decided)}"


def test_the_factory_and_blender_go_torch_and_gpu_payloads_for_others_stay():
    names = _names(distributions())
    assert {"bpy", "numpy", "scipy", "opencv-python-headless", "openexr", "trimesh", "triangle"} <= names
    assert not names & {"torch", "ray", "pip", "matplotlib", "warp-lang", "newton", "zstandard", "cython"}
    assert {"warp-lang", "newton"} <= _names(distributions(newton=True))

    bpy = [d for d in distributions() if d.metadata["Name"] == "bpy"]
    paths = {arcname.split("site-packages/", 1)[1] for _, arcname in site_entries(bpy)}
    kernels = {p.rsplit("/", 1)[1] for p in paths if p.startswith("bpy/5.0/scripts/addons_core/cycles/lib/")}
    assert "bpy/__init__.so" in paths and "bpy/lib/libOpenImageDenoise_device_cpu.so.2.3.3" in paths
    assert {"kernel_compute_75.ptx.zst", "kernel_optix.ptx.zst"} <= kernels  # what an H200 runs
    assert not [k for k in kernels if "gfx" in k or k.startswith("kernel_sm_")]  # AMD kernels, other GPUs' cubins
    assert not [p for p in paths if "__pycache__" in p or "device_hip" in p or "/tests/" in p]

    stdlib = {arcname for _, arcname in python_entries()}
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    assert {f"python/bin/{PYTHON}", f"python/lib/{version}/os.py", f"python/lib/{version}/json/decoder.py"} <= stdlib
    assert any(a.startswith("python/lib/libpython3") for a in stdlib)
    assert not [a for a in stdlib if f"{version}/test/" in a or "tkinter" in a or "site-packages" in a]


def test_calls_carry_the_manifest_and_parts_within_the_budget():
    parts = [(f"p/part.{k:03d}", size) for k, size in enumerate([58, 58, 20, 20, 9])]
    calls = carry_groups(parts, budget=60, manifest="p/MANIFEST.json", max_paths=3)
    assert calls == [["p/MANIFEST.json", "p/part.000"], ["p/MANIFEST.json", "p/part.001"],
                     ["p/MANIFEST.json", "p/part.002", "p/part.003"], ["p/MANIFEST.json", "p/part.004"]]
    with pytest.raises(ValueError, match="p/part.000: .* do not fit one call"):
        carry_groups([("p/part.000", 61)], budget=60, manifest="p/MANIFEST.json")


@pytest.fixture(scope="module")
def small_python(tmp_path_factory):
    """A real relocation at small size: this Python's interpreter, libpython and the standard library
    files that a start, json and importlib load, packed as `pack` packs the factory."""
    base = Path(sys.base_prefix)
    stdlib = base / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}"
    loaded = subprocess.run([str(base / "bin" / PYTHON), "-I", "-c", "import importlib, json, os, sys; print(json.dumps("
                             "[m.__file__ for m in list(sys.modules.values()) if getattr(m, '__file__', None)]))"],
                            capture_output=True, text=True, check=True)
    files = {Path(f) for f in json.loads(loaded.stdout) if Path(f).is_relative_to(stdlib)
             and "site-packages" not in f} | set((stdlib / "encodings").glob("*.py"))
    chosen = {str(f) for f in files}
    entries = [e for e in python_entries() if str(e[0]) in chosen or not e[1].startswith(f"python/lib/{stdlib.name}/")]
    out = tmp_path_factory.mktemp("pack")
    record = pack(out, part_mb=2.0, preset=0, entries=entries, imports=("json",), jobs=2)
    return out, record


def test_a_relocated_python_runs_from_the_unpacked_parts(small_python, tmp_path):
    out, record = small_python
    parts = json.loads((out / "parts" / MANIFEST).read_text())["parts"]
    assert len(parts) > 1 and max(p["bytes"] for p in parts) <= 2 << 20
    result = unpack(out / "parts", tmp_path / "env", jobs=2)
    assert result["prefix"] == str((tmp_path / "env" / "python").resolve()) and result["outside"] == []
    env_sh = (tmp_path / "env" / "env.sh").read_text()
    # a clean shell: env.sh makes python3.11 the relocated one
    ran = subprocess.run(["env", "-i", "PATH=/usr/bin:/bin", "HOME=/tmp", "sh", "-c",
                          f". {tmp_path / 'env' / 'env.sh'}; {PYTHON} -c 'import sys, json; print(sys.prefix)'"],
                         capture_output=True, text=True, check=True)
    assert ran.stdout.strip() == result["prefix"], env_sh


def test_a_damaged_part_is_named_and_nothing_is_extracted(small_python, tmp_path):
    out, _ = small_python
    damaged = tmp_path / "parts"
    damaged.mkdir()
    for path in (out / "parts").iterdir():
        damaged.joinpath(path.name).write_bytes(path.read_bytes())
    data = bytearray((damaged / "part.001").read_bytes())
    data[100] ^= 0xFF
    (damaged / "part.001").write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"part\.001 is damaged"):
        unpack(damaged, tmp_path / "env")
    assert not (tmp_path / "env" / "python").exists()
