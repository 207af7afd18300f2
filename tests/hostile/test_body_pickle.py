"""Hostile SMPL-family model files: pickles that forge numpy's dtype state, byte-mutated pickles,
compressed arrays that decompress to gigabytes, and careless files that used to end in a traceback.

Loads that could crash the interpreter run in a subprocess, so a segfault fails the test (a negative
return code: killed by a signal) instead of killing pytest."""

from __future__ import annotations

import io
import pickle
import re
import subprocess
import sys
import zipfile

import numpy as np
import pytest
import scipy.sparse as sp

from assets.body import load_smpl
from tests.assets.body_fixtures import chumpy_module, smpl_arrays  # noqa: F401 (a fixture)
from tests.hostile.conftest import ROOT

# Loads every file named on the command line with the loader named first; only a ValueError or
# FileNotFoundError naming the file may come out (printed after "refused:").
_LOADER = """
import sys
from assets.body import load_body, load_smpl
load = {"load_smpl": load_smpl, "load_body": load_body}[sys.argv[1]]
for name in sys.argv[2:]:
    print(name, flush=True)
    try:
        load(name)
    except (ValueError, FileNotFoundError) as exc:
        print("refused:", exc, flush=True)
        if name not in str(exc):
            sys.exit(f"{name}: the error does not name the file: {exc}")
print("done", flush=True)
"""


def _load_each(*paths, loader: str = "load_smpl") -> subprocess.CompletedProcess:
    """Load every file in one subprocess (a crash kills it, not pytest) under a 4 GiB address space."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))

    return subprocess.run([sys.executable, "-c", _LOADER, loader, *map(str, paths)], capture_output=True,
                          text=True, cwd=ROOT, timeout=120, preexec_fn=limit)


def _assert_survived(result: subprocess.CompletedProcess) -> None:
    last = [line for line in result.stdout.splitlines() if not line.startswith("refused:")][-1:] or ["(nothing)"]
    assert result.returncode == 0, f"rc {result.returncode} while loading {last[0]}:\n{result.stderr[-3000:]}"
    assert last == ["done"]


class _ForgedDtype:
    """Pickles as numpy's own object dtype whose BUILD state clears its flags: numpy then takes raw
    file bytes as object pointers."""

    def __reduce__(self):
        return (np.dtype, ("O8", False, True), (3, "|", None, None, None, -1, -1, 0))


class _PointerArray:
    """Pickles as an array of the forged dtype holding the pointer 0x4141414141414141 everywhere."""

    def __init__(self, shape):
        self.shape = shape

    def __reduce__(self):
        raw = b"\x41" * (8 * int(np.prod(self.shape)))
        return (np.core.multiarray._reconstruct, (np.ndarray, (0,), b"b"),
                (1, self.shape, _ForgedDtype(), False, raw))


@pytest.fixture
def arrays():
    return smpl_arrays(np.random.default_rng(4), vertices=30)


@pytest.mark.hostile("crash")
def test_forged_object_dtype_is_refused_not_dereferenced(tmp_path, arrays):
    path = tmp_path / "SMPL_NEUTRAL.pkl"
    path.write_bytes(pickle.dumps(dict(arrays, J_regressor=_PointerArray((24, 30))), protocol=2))
    result = _load_each(path)
    _assert_survived(result)
    with pytest.raises(ValueError, match=r"SMPL_NEUTRAL\.pkl: J_regressor must be a numeric array, got an array of dtype 'O8'"):
        load_smpl(path)


class _ForgedByReconstructor:
    """The same forged dtype reached through copyreg's ``_reconstructor`` instead of numpy.dtype."""

    def __reduce__(self):
        import copyreg

        return (copyreg._reconstructor, (np.dtype, np.dtype, "O8"), (3, "|", None, None, None, -1, -1, 0))


@pytest.mark.hostile("crash")
def test_dtype_built_through_copyreg_is_refused(tmp_path, arrays):
    path = tmp_path / "SMPL_MALE.pkl"
    path.write_bytes(pickle.dumps(dict(arrays, weights=_ForgedByReconstructor()), protocol=2))
    with pytest.raises(ValueError, match=r"SMPL_MALE\.pkl: refusing to reconstruct"):
        load_smpl(path)


_OPCODES = b"cR(tb}]qhjgpsua.KMJNIFGXTUBC\x80\x8c\x94\x95"


def _mutants(seed_files: list[bytes], count: int, seed: int = 45) -> list[bytes]:
    """`count` deterministic mutations of the seed files: byte flips, truncations, inserted opcodes,
    duplicated slices."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        raw = bytearray(seed_files[i % len(seed_files)])
        kind = i % 4
        at = int(rng.integers(0, len(raw)))
        if kind == 0:
            for pos in rng.integers(0, len(raw), int(rng.integers(1, 4))):
                raw[pos] = int(rng.integers(0, 256))
        elif kind == 1:
            del raw[at:]
        elif kind == 2:
            raw[at:at] = bytes([_OPCODES[int(rng.integers(0, len(_OPCODES)))]]) + bytes(rng.integers(0, 256, 4).tolist())
        else:
            width = int(rng.integers(1, 64))
            raw[at:at] = raw[max(0, at - width):at]
        out.append(bytes(raw))
    return out


@pytest.mark.hostile("crash")
def test_mutated_pickles_never_crash_or_leak_other_errors(tmp_path, arrays, chumpy_module):
    shapedirs = chumpy_module()
    shapedirs.__dict__.update(x=arrays["shapedirs"], _dirty_vars=set(), label="shapedirs")
    valid = dict(arrays, shapedirs=shapedirs, J_regressor=sp.csc_matrix(arrays["J_regressor"]), bs_style="lbs",
                 f=arrays["f"][:8], posedirs=arrays["posedirs"][:1, :1, :3])
    seeds = [pickle.dumps(valid, protocol=2), pickle.dumps(valid, protocol=4),
             pickle.dumps(dict(arrays, J_regressor=_PointerArray((24, 30))), protocol=2)]
    paths = []
    for i, raw in enumerate(_mutants(seeds, 300)):
        paths.append(tmp_path / f"m{i:03d}.pkl")
        paths[-1].write_bytes(raw)
    _assert_survived(_load_each(*paths))


def _npy_member(shape: tuple[int, ...], dtype: str = "<f8", data: bytes = b"") -> bytes:
    """The bytes of an .npy whose header declares `shape` followed by `data` (however short)."""
    header = {"descr": dtype, "fortran_order": False, "shape": shape}
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, header)
    return buffer.getvalue() + data


def _npz(path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, raw in members.items():
            archive.writestr(f"{name}.npy", raw)


def _npz_of(arrays: dict[str, np.ndarray]) -> dict[str, bytes]:
    out = {}
    for name, array in arrays.items():
        buffer = io.BytesIO()
        np.lib.format.write_array(buffer, np.asarray(array))
        out[name] = buffer.getvalue()
    return out


@pytest.mark.hostile("memory")
def test_npz_declaring_a_huge_template_is_refused_before_allocation(tmp_path, arrays):
    members = _npz_of(arrays)
    members["v_template"] = _npy_member((10**9, 3))  # 24 GB declared, a few bytes stored
    _npz(tmp_path / "bomb.npz", members)
    result = _load_each(tmp_path / "bomb.npz")
    _assert_survived(result)
    assert "the vertex count (v_template) is 1e+09, above the limit" in result.stdout
    assert "max_vertices" in result.stdout


@pytest.mark.hostile("memory")
def test_saved_body_declaring_huge_shape_dirs_is_refused_before_allocation(tmp_path):
    from assets.body import default_body

    body = default_body()
    body.save(tmp_path / "body.npz")
    with zipfile.ZipFile(tmp_path / "body.npz") as archive:
        members = {n[:-4]: archive.read(n) for n in archive.namelist()}
    members["shape_dirs"] = _npy_member((12, 10**8, 3), "<f4")
    members["template"] = _npy_member((10**8, 3), "<f4")
    _npz(tmp_path / "bomb_body.npz", members)
    result = _load_each(tmp_path / "bomb_body.npz", loader="load_body")
    _assert_survived(result)
    assert "the vertex count (template) is 1e+08, above the limit" in result.stdout


def _bad_models(arrays: dict[str, np.ndarray]) -> dict[str, tuple[dict[str, np.ndarray] | bytes, str]]:
    """name -> (arrays of an .npz, raw bytes or None), the text the error must hold."""
    kintree = arrays["kintree_table"].copy()
    kintree[0, 5] = 99
    return {
        "empty": (b"", "not a readable .npz"),
        "kintree_out_of_range": (dict(arrays, kintree_table=kintree), "parents must list each joint"),
        "faces_past_vertices": (dict(arrays, f=arrays["f"] + 1000), "faces index outside"),
        "regressor_of_text": (dict(arrays, J_regressor=np.full((24, 30), "x")), "J_regressor must be a numeric array"),
        "template_1d": (dict(arrays, v_template=arrays["v_template"].ravel()), "v_template must be a 2-D array"),
        "weights_wrong_shape": (dict(arrays, weights=arrays["weights"][:, :10]), "weights has shape (30, 10)"),
        "template_nan": (dict(arrays, v_template=np.full((30, 3), np.nan)), "v_template holds NaN"),
        "corrupt_deflate": (None, "not a readable .npz"),  # written by the test
    }


@pytest.mark.parametrize("case", ["empty", "kintree_out_of_range", "faces_past_vertices", "regressor_of_text",
                                  "template_1d", "weights_wrong_shape", "corrupt_deflate"])
@pytest.mark.hostile("traceback")
def test_careless_npz_models_are_refused_naming_file_and_field(tmp_path, arrays, case):
    content, needle = _bad_models(arrays)[case]
    path = tmp_path / f"{case}.npz"
    if case == "corrupt_deflate":
        np.savez_compressed(path, **arrays)
        raw = bytearray(path.read_bytes())
        start = raw.index(b"v_template.npy") + len("v_template.npy")
        raw[start + 200:start + 260] = bytes(60)  # inside the deflate stream of v_template
        path.write_bytes(bytes(raw))
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        np.savez(path, **content)
    with pytest.raises(ValueError) as caught:
        load_smpl(path)
    assert str(path) in str(caught.value) and needle in str(caught.value), caught.value


@pytest.mark.hostile("silent")
def test_nan_template_is_refused(tmp_path, arrays):
    content, needle = _bad_models(arrays)["template_nan"]
    np.savez(tmp_path / "nan.npz", **content)
    with pytest.raises(ValueError, match=r"nan\.npz: v_template holds NaN"):
        load_smpl(tmp_path / "nan.npz")


@pytest.mark.parametrize("payload, needle", [
    ([1, 2, 3], "a model pickle holds a dict, found list"),
    ("sparse", "J_regressor: a sparse matrix whose indptr or indices point outside"),
])
@pytest.mark.hostile("traceback")
def test_careless_pickles_are_refused_naming_file_and_field(tmp_path, arrays, payload, needle):
    if payload == "sparse":
        matrix = sp.csc_matrix(arrays["J_regressor"])
        matrix.indices[0] = 500  # scipy itself would refuse it naming no file
        payload = dict(arrays, J_regressor=matrix)
    path = tmp_path / "model.pkl"
    path.write_bytes(pickle.dumps(payload, protocol=2))
    with pytest.raises(ValueError, match=re.escape(f"{path}: ") + ".*" + re.escape(needle)):
        load_smpl(path)
