"""Restricted reading of untrusted SMPL-family `.pkl` files: numeric arrays, scipy sparse matrices and
chumpy arrays as plain data, and nothing else.

Nothing of the file's reaches numpy's own unpickling.  The names a model pickle uses for arrays
(``numpy.dtype``, numpy's ``_reconstruct``, ``scalar`` and ``_frombuffer``) resolve to stand-ins that
accept only numeric type codes (bool, int/uint 8-64, float 16-64, complex 64/128) with a byte order,
and build each array from its raw bytes after checking that their length is what the declared shape
needs.  So a file can neither run code, nor forge a dtype's state (an object dtype whose flags a BUILD
clears makes numpy read file bytes as object pointers), nor declare an array larger than the bytes it
brings.  Arrays of any other dtype (object, strings, structured) become `Unreadable` values that a
reader refuses if it needs them.  Before anything is built the opcode stream is scanned
(`pickletools.genops`), so lengths and memo indices that would make the unpickler itself allocate
gigabytes are refused first.
"""

from __future__ import annotations

import codecs
import io
import pickle
import pickletools

import numpy as np
import scipy.sparse as sp

#: Type codes of the dtypes a model array may have.
NUMERIC_CODES = frozenset({"b1", "i1", "u1", "i2", "u2", "i4", "u4", "i8", "u8", "f2", "f4", "f8", "c8", "c16"})
_BYTE_ORDERS = ("<", ">", "|", "=")
_PUT_OPCODES = ("PUT", "BINPUT", "LONG_BINPUT")


class Unreadable:
    """Stands for an array the file holds in a dtype model files never need (object, string,
    structured); `reason` says which."""

    def __init__(self, reason: str):
        self.reason = reason

    def __repr__(self) -> str:
        return self.reason


class _Captured:
    """Plain stand-in for the pickled objects we accept but do not import (chumpy arrays, scipy
    sparse matrices of any scipy version): it only records its pickled state."""

    state: dict = {}

    def __setstate__(self, state):
        self.state = state if isinstance(state, dict) else {"state": state}


class _Chumpy(_Captured):
    pass


class _Sparse(_Captured):
    format = "csc"


_SPARSE = {name: type(name, (_Sparse,), {"format": name[:3]}) for name in ("csc_matrix", "csr_matrix", "coo_matrix")}


class _Ndarray:
    """What the file's ``numpy.ndarray`` resolves to: only a tag for `_reconstruct`."""


class _Dtype:
    """A dtype named by the file: a type code and, after BUILD, a byte order; `dtype` is None for a
    code outside `NUMERIC_CODES`."""

    def __init__(self, code: object, align: object = False, copy: object = True):
        code = code.decode("latin1") if isinstance(code, bytes) else code
        self.code = code
        self.dtype = np.dtype(code) if isinstance(code, str) and code in NUMERIC_CODES else None

    def __setstate__(self, state):
        # numpy's state: (version, byte order, subarray, names, fields, elsize, alignment, flags[, metadata])
        if not (isinstance(state, tuple) and len(state) in (8, 9) and state[0] in (3, 4)):
            raise pickle.UnpicklingError(f"dtype {self.code!r}: unexpected state {type(state).__name__}")
        order, subarray, names, fields, flags = state[1], state[2], state[3], state[4], state[7]
        if subarray is not None or names is not None or fields is not None or flags != 0:
            self.dtype = None  # structured, sub-array or flagged (object-like): never model data
        elif self.dtype is not None:
            if order not in _BYTE_ORDERS:
                raise pickle.UnpicklingError(f"dtype {self.code!r}: byte order {order!r}")
            self.dtype = self.dtype.newbyteorder(order)

    def unreadable(self) -> Unreadable:
        return Unreadable(f"an array of dtype {self.code!r} (model arrays are numeric: {', '.join(sorted(NUMERIC_CODES))})")


def _raw_bytes(data: object) -> bytes:
    if isinstance(data, str):  # Python 2 pickles' byte strings, read as latin-1 text
        return data.encode("latin1")
    if isinstance(data, (bytes, bytearray)):
        return bytes(data)
    raise pickle.UnpicklingError(f"array data must be bytes, got {type(data).__name__}")


def _build(dtype: object, shape: object, data: object, fortran: object = False) -> np.ndarray | Unreadable:
    """The array of `shape` and `dtype` (a `_Dtype`) from raw `data`, whose length must match."""
    if not isinstance(dtype, _Dtype):
        raise pickle.UnpicklingError(f"an array's dtype must be a numpy dtype, got {type(dtype).__name__}")
    if dtype.dtype is None:
        return dtype.unreadable()
    if not (isinstance(shape, tuple) and len(shape) <= 32 and all(type(n) is int and n >= 0 for n in shape)):
        raise pickle.UnpicklingError(f"an array's shape must be a tuple of sizes, got {shape!r:.80}")
    raw = _raw_bytes(data)
    need = int(np.prod(shape, dtype=object)) * dtype.dtype.itemsize
    if len(raw) != need:
        raise pickle.UnpicklingError(f"an array of shape {shape} {dtype.dtype} needs {need} bytes, the file has {len(raw)}")
    return np.frombuffer(raw, dtype.dtype).reshape(shape, order="F" if fortran else "C").copy()


class _Array:
    """What numpy's ``_reconstruct`` returns: its BUILD state (version, shape, dtype, Fortran order,
    raw data) makes `value` the array, or an `Unreadable`."""

    value: np.ndarray | Unreadable = Unreadable("an array without data")

    def __setstate__(self, state):
        if isinstance(state, tuple) and len(state) == 5:
            state = state[1:]
        if not (isinstance(state, tuple) and len(state) == 4):
            raise pickle.UnpicklingError(f"unexpected array state {type(state).__name__}")
        shape, dtype, fortran, data = state
        self.value = _build(dtype, shape, data, bool(fortran))


def _reconstruct(subtype: object, shape: object, code: object) -> _Array:
    if subtype is not _Ndarray:
        raise pickle.UnpicklingError("numpy's array reconstruction may only build numpy.ndarray")
    return _Array()


def _scalar(dtype: object, data: object = b"") -> np.generic | Unreadable:
    value = _build(dtype, (), data)
    return value if isinstance(value, Unreadable) else value[()]


def _frombuffer(buffer: object, dtype: object, shape: object, order: object) -> np.ndarray | Unreadable:
    return _build(dtype, shape, buffer, order == "F")


def _reconstructor(cls: object, base: object, state: object = None) -> _Captured:
    """copyreg's helper for protocol 0/1 objects, for the captured classes only."""
    if not (isinstance(cls, type) and issubclass(cls, _Captured) and base is object and state is None):
        raise pickle.UnpicklingError(f"refusing to reconstruct {cls!r:.60} from {base!r:.60}")
    return cls()


def _encode(text: object, encoding: object = "latin1") -> bytes:
    """Python 3 writes bytes into protocol-2 pickles as ``_codecs.encode(text, "latin1")``."""
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise pickle.UnpicklingError(f"refusing _codecs.encode with encoding {encoding!r:.40}")
    return codecs.encode(text, "latin1")


_ALLOWED: dict[tuple[str, str], object] = {
    ("numpy", "ndarray"): _Ndarray,
    ("numpy", "dtype"): _Dtype,
    ("copy_reg", "_reconstructor"): _reconstructor,
    ("copyreg", "_reconstructor"): _reconstructor,
    ("_codecs", "encode"): _encode,
}
# Plain containers (chumpy's pickled state holds sets); building them runs no code of the file's choosing.
for _builtins in ("__builtin__", "builtins"):
    for _type in (object, set, frozenset, slice, complex):
        _ALLOWED[(_builtins, _type.__name__)] = _type
for _core in ("numpy.core", "numpy._core"):
    _ALLOWED[(f"{_core}.multiarray", "_reconstruct")] = _reconstruct
    _ALLOWED[(f"{_core}.multiarray", "scalar")] = _scalar
    _ALLOWED[(f"{_core}.numeric", "_frombuffer")] = _frombuffer  # protocol 5


class SafeUnpickler(pickle.Unpickler):
    """Unpickler that can build numeric arrays, sparse matrices and chumpy data, and nothing else."""

    def find_class(self, module: str, name: str):
        if (module, name) in _ALLOWED:
            return _ALLOWED[(module, name)]
        if module.startswith("chumpy"):
            return _Chumpy
        if module.startswith("scipy.sparse") and name in _SPARSE:
            return _SPARSE[name]
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}: model files may contain only arrays")


def _scan(raw: bytes) -> None:
    """Refuse an opcode stream that would make the unpickler allocate far beyond the file's size: a
    memo index past the entries stored so far (the memo is a table sized by the largest index) or a
    frame longer than the file.  Malformed streams fail here too, with a ValueError."""
    puts = 0
    for opcode, arg, position in pickletools.genops(io.BytesIO(raw)):
        if opcode.name in _PUT_OPCODES:
            if arg > puts:
                raise ValueError(f"memo index {arg} at byte {position} skips ahead of the {puts} entries stored")
            puts += 1
        elif opcode.name == "MEMOIZE":
            puts += 1
        elif opcode.name == "FRAME" and arg > len(raw):
            raise ValueError(f"a frame of {arg} bytes at byte {position} in a file of {len(raw)}")
        elif opcode.name == "PROTO" and arg > pickle.HIGHEST_PROTOCOL:
            raise ValueError(f"pickle protocol {arg}")


def load_pickle(raw: bytes, source: str) -> object:
    """Unpickle `raw` with `SafeUnpickler` after `_scan`; any malformed or refused content is a
    ValueError naming `source`."""
    try:
        _scan(raw)
        return SafeUnpickler(io.BytesIO(raw), encoding="latin1").load()
    except pickle.UnpicklingError as exc:
        raise ValueError(f"{source}: {exc}") from exc
    except (EOFError, TypeError, AttributeError, IndexError, KeyError, ValueError, OverflowError) as exc:
        raise ValueError(f"{source}: not a readable model pickle ({type(exc).__name__}: {exc})") from exc


def _numeric(value: object, what: str, ndim: int | None = None, integer: bool = False) -> np.ndarray:
    """`value` (an array read by the unpickler) if it is a numeric array of `ndim` dimensions."""
    if isinstance(value, _Array):
        value = value.value
    kinds = "iu" if integer else "biufc"
    if not (isinstance(value, np.ndarray) and value.dtype.kind in kinds and (ndim is None or value.ndim == ndim)):
        got = value if isinstance(value, Unreadable) else f"{type(value).__name__} {getattr(value, 'shape', '')}"
        dims = "" if ndim is None else f"{ndim}-D "
        raise ValueError(f"{what} must be a {dims}{'integer' if integer else 'numeric'} array, got {got}")
    return value


def _sparse(value: _Sparse, what: str) -> sp.spmatrix:
    """The scipy matrix of a captured csc/csr matrix, after checking its parts as numeric arrays of
    consistent sizes (scipy trusts them)."""
    if value.format not in ("csc", "csr"):
        raise ValueError(f"{what}: a {value.format} sparse matrix; model files hold csc or csr")
    s = value.state
    missing = [k for k in ("data", "indices", "indptr") if k not in s]
    shape = s.get("_shape", s.get("shape"))
    if missing or shape is None:
        raise ValueError(f"{what}: a sparse matrix without {', '.join(missing) or 'shape'}")
    if not (isinstance(shape, tuple) and len(shape) == 2 and all(isinstance(n, (int, np.integer)) and n >= 0 for n in shape)):
        raise ValueError(f"{what}: a sparse matrix's shape must be two sizes, got {shape!r:.80}")
    data = _numeric(s["data"], f"{what}: data", 1)
    indices = _numeric(s["indices"], f"{what}: indices", 1, integer=True)
    indptr = _numeric(s["indptr"], f"{what}: indptr", 1, integer=True)
    major, minor = (shape[1], shape[0]) if value.format == "csc" else shape
    if len(indices) != len(data) or len(indptr) != major + 1:
        raise ValueError(f"{what}: a {shape} sparse matrix needs indptr of {major + 1} and indices as long as "
                         f"data ({len(data)}), got {len(indptr)} and {len(indices)}")
    if (len(indptr) and (indptr[0] != 0 or indptr[-1] != len(data) or np.any(np.diff(indptr) < 0))
            or np.any(indices < 0) or np.any(indices >= minor)):
        raise ValueError(f"{what}: a sparse matrix whose indptr or indices point outside its {shape}")
    cls = sp.csc_matrix if value.format == "csc" else sp.csr_matrix
    return cls((data, indices.astype(np.int64), indptr.astype(np.int64)), shape=tuple(map(int, shape)))


def plain(value: object, what: str) -> object:
    """A value read by `load_pickle` as plain data: arrays (or `Unreadable`), a chumpy array's stored
    data, a checked scipy sparse matrix; anything else as it is.  `what` names it in errors."""
    if isinstance(value, _Array):
        return value.value
    if isinstance(value, _Chumpy):
        if "x" not in value.state:
            raise ValueError(f"{what} is a chumpy expression, not stored data; re-export it as an array")
        return _numeric(value.state["x"], what)
    if isinstance(value, _Sparse):
        return _sparse(value, what)
    return value
