"""The factory on the GPU machine: this project's Python 3.11, the factory's packages and Blender carried
there in checked parts, so a recipe's data is made where it is trained.

The GPU machine (KINDS.md: 16 cores, an H200, Ubuntu's Python 3.12 with torch) has no bpy, and bpy
5.0.1 exists for Python 3.11 only; nothing can be installed there.  So `pack` takes from this machine:
- the interpreter (pyenv's python3.11 and libpython3.11.so) and its standard library, without its
  tests, Tk, IDLE, ensurepip, 2to3 and static library;
- the venv's distributions that the factory imports (`FACTORY_DISTRIBUTIONS` and what they require),
  without tests and caches: no torch, ray, pip, matplotlib; Blender without its AMD (HIP) kernels,
  its NVIDIA cubins (none is for the H200's sm_90: Cycles JIT-compiles the PTX there) and OptiX OSL
  kernels, the HIP and SYCL denoiser devices, Blender's own USD/MaterialX/OpenImageIO/OpenColorIO/
  OpenVDB bindings, its UI asset library and CJK and emoji fonts (`SITE_SKIP`);
- the system libraries those link that the machine need not have (X11 and GL client libraries,
  OpenSSL, libffi, ...: whatever `ldd` finds outside glibc and the GCC runtime, `DEVICE_LIBS`).
They travel as xz archives (LZMA2 preset 9, the x86 branch filter on ELF files: 10% smaller than
`zstd -19 --long` on a Blender library, and any Python's standard library unpacks them, so the
machine needs no zstd) in parts of at most 58 MiB (`benchmarks/device_files.py`: each part's and each
file's SHA-256), one part a call: a call carries at most 64 MiB, the working tree's ~5 MiB included.
About 1 GiB goes as 0.27 GiB in 5 parts (docs/journal/2026-11-29-factory-on-device.md).

The factory's cloth simulation (`factory.cloth`, dressing included) is projective dynamics on scipy:
it needs neither warp nor Newton.  `--newton` adds warp-lang and Newton (reconstruction's refine);
warp's CUDA needs only the driver's libcuda, which the machine has (warp.so links glibc alone and
carries its own NVRTC).

    here:    python benchmarks/device_factory.py pack out/device_factory [--newton]
             (a few minutes per changed archive; unchanged ones are kept; writes
             out/device_factory/parts/ and calls.json, and prints the calls)
    calls 1 .. P-1, back to back (the machine goes back 30 s after a call), each carrying
             out/device_factory/parts/MANIFEST.json and one part:
             python3 benchmarks/device_files.py send out/device_factory/parts /tmp/fparts --parts K
    call P:  the same, then
             python3 benchmarks/device_factory.py unpack /tmp/fparts /tmp/fenv
             (checks every part, extracts in parallel, writes /tmp/fenv/bin/python3.11 and
             /tmp/fenv/env.sh, then imports every package with the relocated Python and names any
             library it took from outside /tmp/fenv besides glibc and the GCC runtime)
             . /tmp/fenv/env.sh     # python3.11 is the relocated one; python3 stays the machine's
             then the build, detached (`benchmarks/device_recipe.py`):
             mkdir -p /tmp/data && setsid nohup python3.11 benchmarks/device_recipe.py all_garments \\
                 --out /tmp/data/all_garments > /tmp/data/build.log 2>&1 < /dev/null &
             sleep 30; tail -3 /tmp/data/build.log    # alive and logging before the call returns
    later calls: python3 benchmarks/device_files.py wait /tmp/data/all_garments/factory_run.done --timeout 570
             (or tail the log); then train with the machine's python3 on the folder:
             python3 -m networks.train localizer --recipe all_garments --data /tmp/data/all_garments ...

`bin/python3.11` is a small script that sets PYTHONHOME and LD_LIBRARY_PATH for the relocated
interpreter and what it starts, so sourcing env.sh (which only puts it first on PATH) leaves the
machine's python3 and torch untouched in the same shell.  No display is needed: bpy renders in the
background; its X11/GL libraries are loaded, never used.

The device side (`unpack`) uses the standard library only and runs on any Python 3.9+.
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import json
import lzma
import os
import re
import shlex
import shutil
import subprocess
import sys
import tarfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.device_files import MANIFEST, pack as pack_parts, unpack as unpack_parts  # noqa: E402

#: the venv's distributions the factory imports (`pyproject.toml`'s dependencies and `factory` extra);
#: networkx and rtree are trimesh's optional graph and spatial-index backends, imported on its way
FACTORY_DISTRIBUTIONS = ("bpy", "numpy", "scipy", "opencv-python-headless", "pillow", "OpenEXR", "trimesh",
                         "networkx", "rtree", "triangle", "xatlas", "tqdm")
#: project dependencies the factory never imports: motion previews (matplotlib), reading videos (av)
LEFT_OUT = ("matplotlib", "av")
#: bpy's declared requirements that rendering never imports (its downloader and .blend header reader)
UNUSED_REQUIREMENTS = ("cython", "requests", "zstandard")
#: reconstruction's refine (`--newton`)
NEWTON_DISTRIBUTIONS = ("warp-lang", "newton")
#: libraries every Linux machine with glibc and a C++ runtime has: never carried (the machine's own
#: libstdc++ is newer than this Debian 12's; `unpack` checks the versions the payload needs)
DEVICE_LIBS = ("linux-vdso.so.1", "ld-linux-x86-64.so.2", "libc.so.6", "libm.so.6", "libdl.so.2", "libpthread.so.0",
               "librt.so.1", "libutil.so.1", "libresolv.so.2", "libstdc++.so.6", "libgcc_s.so.1")
#: the GPU driver's libraries, which the machine has and this one need not (loaded by GPU backends only)
DRIVER_LIBS = ("libcuda.so.1",)
#: system libraries loaded with dlopen, which ldd does not see: Pillow's text layout loads FriBiDi
DLOPENED = ("libfribidi.so.0",)
#: standard library folders (and files) the factory never uses
STDLIB_SKIP = ("test/*", "idlelib/*", "tkinter/*", "turtledemo/*", "ensurepip/*", "lib2to3/*", "pydoc_data/*",
               "site-packages/*", "config-3.*/*", "*/test/*", "*/tests/*", "*/idle_test/*", "*.pyc",
               "lib-dynload/_tkinter*", "lib-dynload/_test*", "lib-dynload/_ctypes_test*", "lib-dynload/_xxtestfuzz*")
#: site-packages files never needed: caches, tests, and Blender's payloads for other hardware and uses
_CYCLES = "bpy/5.0/scripts/addons_core/cycles/lib/"
SITE_SKIP = ("*.pyc", "*/tests/*", "warp/examples/*", "newton/examples/*", "cv2/data/*",  # face detectors
             _CYCLES + "*gfx*",                   # AMD HIP kernels
             _CYCLES + "kernel_sm_*.cubin*",      # no NVIDIA cubin runs on the H200 (sm_90): it JITs the PTX
             _CYCLES + "kernel_optix_osl*",       # OSL shading on OptiX: the factory's materials are nodes
             "bpy/lib/libOpenImageDenoise_device_hip*", "bpy/lib/libOpenImageDenoise_device_sycl*",
             "bpy/5.0/python/lib/python3.11/site-packages/*",  # USD, MaterialX, OIIO, OCIO, VDB bindings
             "bpy/5.0/datafiles/assets/*",        # brushes and node groups of the UI's asset library
             "bpy/5.0/datafiles/fonts/Noto Sans CJK*", "bpy/5.0/datafiles/fonts/NotoEmoji*")  # UI text
#: what `unpack` imports with the relocated Python to check it (the factory's, and `--newton`'s)
FACTORY_IMPORTS = ("numpy", "scipy.sparse.linalg", "scipy.spatial", "cv2", "PIL.Image", "OpenEXR", "trimesh",
                   "triangle", "rtree", "networkx", "tqdm", "bpy", "_cycles")
NEWTON_IMPORTS = ("warp", "newton")
#: largest archive before compression: enough archives to unpack in parallel on 16 cores
ARCHIVE_BYTES = 128 << 20
PAYLOAD = "PAYLOAD.json"
PART_MB = 58.0
#: what one call carries at most (the working tree included), and the paths it names
CALL_BYTES, CALL_PATHS = 64 << 20, 8
PYTHON = "python3.11"

Entry = tuple[Path, str]  # (file here, its path in the relocated tree)


# ---- here: what goes -----------------------------------------------------------------------------
def _skipped(rel: str, patterns: tuple[str, ...]) -> bool:
    return any(fnmatch.fnmatchcase(rel, p) for p in patterns)


def distributions(newton: bool = False) -> list:
    """The installed distributions to carry: `FACTORY_DISTRIBUTIONS` (and `NEWTON_DISTRIBUTIONS`) with
    everything they require, less `UNUSED_REQUIREMENTS`; a LookupError names one not installed."""
    from importlib import metadata

    from packaging.requirements import Requirement

    wanted, found = list(FACTORY_DISTRIBUTIONS + (NEWTON_DISTRIBUTIONS if newton else ())), {}
    while wanted:
        name = wanted.pop()
        key = re.sub(r"[-_.]+", "-", name).lower()
        if key in found or key in UNUSED_REQUIREMENTS:
            continue
        try:
            dist = found[key] = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            raise LookupError(f"{name} is not installed in {sys.prefix}: the factory needs it (make test installs it)")
        for spec in dist.requires or ():
            requirement = Requirement(spec)
            if requirement.marker is None or requirement.marker.evaluate({"extra": ""}):
                wanted.append(requirement.name)
    return [found[k] for k in sorted(found)]


def python_entries(prefix: Path | None = None) -> list[Entry]:
    """The interpreter, libpython and the standard library of `prefix` (default: this Python's base),
    laid out as ``python/bin``, ``python/lib``."""
    prefix = Path(prefix or sys.base_prefix)
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    stdlib = prefix / "lib" / version
    entries = [(prefix / "bin" / version, f"python/bin/{PYTHON}")]
    entries += [(p, f"python/lib/{p.name}") for p in sorted((prefix / "lib").glob("libpython3*.so*")) if not p.is_symlink()]
    for path in sorted(stdlib.rglob("*")):
        rel = path.relative_to(stdlib).as_posix()
        if path.is_file() and not _skipped(rel, STDLIB_SKIP):
            entries.append((path, f"python/lib/{version}/{rel}"))
    return entries


def site_entries(dists: list) -> list[Entry]:
    """The files of `dists` (their RECORDs) inside site-packages, less `SITE_SKIP`."""
    entries = {}
    for dist in dists:
        site = Path(dist.locate_file("")).resolve()
        for file in dist.files or ():
            rel = file.as_posix()
            path = site / file
            if rel.startswith("..") or _skipped(rel, SITE_SKIP) or not path.is_file():
                continue
            entries[rel] = (path, f"python/lib/python{sys.version_info.major}.{sys.version_info.minor}/site-packages/{rel}")
    return [entries[k] for k in sorted(entries)]


def _is_elf(path: Path) -> bool:
    with open(path, "rb") as f:
        return f.read(4) == b"\x7fELF"


def _ldd(path: Path, library_path: str) -> list[tuple[str, str | None]]:
    """(soname, the file it resolves to, or None when not found) of every library `path` loads."""
    out = subprocess.run(["ldd", str(path)], capture_output=True, text=True,
                         env={**os.environ, "LD_LIBRARY_PATH": library_path})
    found = []
    for line in out.stdout.splitlines():
        name, arrow, rest = line.strip().partition(" => ")
        if arrow:
            target = rest.split(" (")[0].strip()
            found.append((name, None if target == "not found" else target))
        elif line.strip().startswith("/"):
            found.append((Path(line.split()[0]).name, line.split()[0]))
    return found


def system_libraries(entries: list[Entry], prefix: Path | None = None) -> tuple[list[Entry], list[str]]:
    """(``lib/<soname>`` entries, problems): the libraries the ELF files of `entries` load from outside
    them, but for `DEVICE_LIBS` and `DRIVER_LIBS`, and `DLOPENED`; problems name libraries not found
    or found outside this tree's files."""
    from concurrent.futures import ThreadPoolExecutor

    prefix = Path(prefix or sys.base_prefix)
    packed = {str(src.resolve()) for src, _ in entries}
    elf = [src for src, _ in entries if _is_elf(src)]
    with ThreadPoolExecutor(max_workers=8) as pool:
        resolved = dict(zip(elf, pool.map(lambda p: _ldd(p, str(prefix / "lib")), elf)))
    # a wheel's bundled libraries (numpy.libs/...) find each other through the extension that loads
    # them first, not through their own search path: ldd of one alone does not find its siblings
    names = {Path(arcname).name for _, arcname in entries}
    carried, problems = {}, set()
    for src, libraries in resolved.items():
        for name, target in libraries:
            if name in DEVICE_LIBS or name in DRIVER_LIBS:
                continue
            if target is None:
                if name not in names:
                    problems.add(f"{src}: {name} not found")
            elif str(Path(target).resolve()) in packed:
                continue
            elif str(Path(target).resolve()).startswith((str(prefix), sys.prefix)):
                problems.add(f"{src}: {name} resolves to {target}, which the pack leaves out")
            else:
                carried.setdefault(name, Path(target).resolve())
    listed = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout.splitlines()
    for name in DLOPENED:
        found = [line.split(" => ")[-1].strip() for line in listed if line.strip().startswith(name + " ")]
        if found:
            carried.setdefault(name, Path(found[0]).resolve())
        else:
            problems.add(f"{name} (dlopened) not found on this machine")
    return [(path, f"lib/{name}") for name, path in sorted(carried.items())], sorted(problems)


def _max_version(entries: list[Entry], tag: bytes) -> str | None:
    """The highest symbol version `tag`_x.y[.z] the ELF files of `entries` ask for (e.g. GLIBC_2.34)."""
    pattern, best = re.compile(re.escape(tag) + rb"_(\d+(?:\.\d+)+)\x00"), None
    for src, _ in entries:
        if _is_elf(src):
            for match in pattern.finditer(src.read_bytes()):
                version = tuple(int(v) for v in match.group(1).split(b"."))
                best = max(best or version, version)
    return ".".join(map(str, best)) if best else None


# ---- here: archives and parts -------------------------------------------------------------------
def _archives(entries: list[Entry]) -> dict[str, list[Entry]]:
    """{archive name: entries}: ELF files (``elf-NN``) apart from the rest (``data-NN``), in path order,
    at most `ARCHIVE_BYTES` each (a larger file alone)."""
    groups: dict[str, list[Entry]] = {}
    for kind in ("elf", "data"):
        chosen = sorted((e for e in entries if _is_elf(e[0]) == (kind == "elf")), key=lambda e: e[1])
        size, index = 0, -1
        for entry in chosen:
            bytes_ = entry[0].stat().st_size
            if index < 0 or size + bytes_ > ARCHIVE_BYTES:
                index, size = index + 1, 0
            groups.setdefault(f"{kind}-{index:02d}.tar.xz", []).append(entry)
            size += bytes_
    return groups


def _filters(name: str, preset: int) -> list[dict]:
    lzma2 = {"id": lzma.FILTER_LZMA2, "preset": preset}
    return [{"id": lzma.FILTER_X86}, lzma2] if name.startswith("elf") else [lzma2]


def _content_key(name: str, entries: list[Entry], preset: int) -> str:
    """What an archive holds (paths, sizes, times, modes) and how it is compressed, as one digest."""
    digest = hashlib.sha256(f"{name} {preset}".encode())
    for src, arcname in entries:
        st = src.stat()
        digest.update(f"{arcname}\0{src}\0{st.st_size}\0{st.st_mtime_ns}\0{st.st_mode}\n".encode())
    return digest.hexdigest()


def _normalised(info: tarfile.TarInfo) -> tarfile.TarInfo:
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    return info


def _write_archive(path: Path, entries: list[Entry], preset: int) -> int:
    """`entries` as an xz-compressed tar at `path` (written atomically); returns its size."""
    partial = path.with_name(path.name + ".partial")
    with lzma.open(partial, "wb", format=lzma.FORMAT_XZ, filters=_filters(path.name, preset)) as xz:
        with tarfile.open(fileobj=xz, mode="w|", format=tarfile.PAX_FORMAT, dereference=True) as tar:
            for src, arcname in entries:
                tar.add(str(src), arcname=arcname, recursive=False, filter=_normalised)
    os.replace(partial, path)
    return path.stat().st_size


def _tree_bytes() -> int:
    """Bytes of what a device call takes along besides its carry: tracked and untracked-not-ignored files."""
    listed = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                            capture_output=True, check=True).stdout.split(b"\0")
    return sum((ROOT / os.fsdecode(p)).stat().st_size for p in listed if p and (ROOT / os.fsdecode(p)).is_file())


def carry_groups(parts: list[tuple[str, int]], budget: int, manifest: str, max_paths: int = CALL_PATHS) -> list[list[str]]:
    """Each call's carry list: `manifest` and consecutive parts ((path, bytes)), at most `budget` bytes
    and `max_paths` paths in all; a ValueError names a part that fits no call."""
    calls: list[list[str]] = []
    size = budget + 1
    for path, bytes_ in parts:
        if bytes_ > budget:
            raise ValueError(f"{path}: {bytes_ / 2**20:.1f} MiB do not fit one call's {budget / 2**20:.1f} MiB "
                             "beside the working tree; pack with a smaller --part-mb")
        if size + bytes_ > budget or len(calls[-1]) >= max_paths:
            calls.append([manifest])
            size = 0
        calls[-1].append(path)
        size += bytes_
    return calls


def pack(out: Path, newton: bool = False, part_mb: float = PART_MB, preset: int = 9,
         entries: list[Entry] | None = None, imports: tuple[str, ...] = (), jobs: int | None = None) -> dict:
    """Write the payload (archives and ``PAYLOAD.json``) under ``out/payload`` and its checked parts
    under ``out/parts``; returns the payload's record.  `entries`: what to carry, and `imports` what
    `unpack` imports to check it (default: this Python, the factory's distributions and the system
    libraries they load, and `FACTORY_IMPORTS`); archives whose contents are unchanged since the last
    pack are kept."""
    out = Path(out)
    payload, parts = out / "payload", out / "parts"
    problems: list[str] = []
    if entries is None:
        entries = python_entries() + site_entries(distributions(newton))
        libraries, problems = system_libraries(entries)
        entries += libraries
        imports = FACTORY_IMPORTS + (NEWTON_IMPORTS if newton else ())
    groups = _archives(entries)
    previous = {}
    if (payload / PAYLOAD).is_file():
        previous = {a["name"]: a["key"] for a in json.loads((payload / PAYLOAD).read_text()).get("archives", [])}
    payload.mkdir(parents=True, exist_ok=True)
    for stale in payload.iterdir():
        if stale.name not in groups:
            stale.unlink()
    keys = {name: _content_key(name, group, preset) for name, group in groups.items()}
    todo = [n for n in groups if previous.get(n) != keys[n] or not (payload / n).is_file()]
    todo.sort(key=lambda n: -sum(src.stat().st_size for src, _ in groups[n]))
    started = time.perf_counter()
    with ProcessPoolExecutor(max_workers=jobs or os.cpu_count()) as pool:
        list(pool.map(_write_archive, [payload / n for n in todo], [groups[n] for n in todo], [preset] * len(todo)))
    record = {
        "python": sys.version.split()[0], "imports": list(imports), "glibc": _max_version(entries, b"GLIBC"),
        "glibcxx": _max_version(entries, b"GLIBCXX"), "problems": problems, "compress_s": time.perf_counter() - started,
        "archives": [{"name": n, "key": keys[n], "files": len(groups[n]),
                      "bytes_in": sum(src.stat().st_size for src, _ in groups[n]),
                      "bytes": (payload / n).stat().st_size} for n in sorted(groups)],
    }
    (payload / PAYLOAD).write_text(json.dumps(record, indent=1))
    shutil.rmtree(parts, ignore_errors=True)
    pack_parts(payload, parts, part_mb)
    return record


def calls(out: Path, budget: int | None = None) -> list[dict]:
    """The device calls that bring ``out/parts`` over: each one's carry list and command; the last also
    unpacks.  `budget`: bytes a call may carry (default: 64 MiB less the working tree)."""
    parts = Path(out) / "parts"
    manifest = json.loads((parts / MANIFEST).read_text())
    rel = parts.resolve().relative_to(ROOT).as_posix()
    budget = CALL_BYTES - _tree_bytes() - (parts / MANIFEST).stat().st_size if budget is None else budget
    groups = carry_groups([(f"{rel}/{p['name']}", p["bytes"]) for p in manifest["parts"]], budget, f"{rel}/{MANIFEST}")
    plan, first = [], 0
    for group in groups:
        numbers = f"{first}-{first + len(group) - 2}"
        command = f"python3 benchmarks/device_files.py send {rel} /tmp/fparts --parts {numbers}"
        plan.append({"carry": group, "command": command})
        first += len(group) - 1
    plan[-1]["command"] += " && python3 benchmarks/device_factory.py unpack /tmp/fparts /tmp/fenv"
    return plan


# ---- the device: unpack -------------------------------------------------------------------------
def _extract(archive: str, dest: str) -> int:
    """Extract the xz tar `archive` under `dest` in one pass; returns the number of files."""
    count = 0
    with tarfile.open(archive, mode="r|xz") as tar:
        for member in tar:
            if hasattr(tarfile, "data_filter"):  # Python 3.12, 3.11.4+: no path outside dest, no odd files
                tar.extract(member, dest, filter="data")
            else:
                target = os.path.realpath(os.path.join(dest, member.name))
                if not target.startswith(os.path.realpath(dest) + os.sep) or not member.isfile():
                    raise ValueError(f"{archive}: {member.name!r} is not a plain file inside the destination")
                tar.extract(member, dest)
            count += 1
    return count


def _version(text: str | None) -> tuple[int, ...]:
    return tuple(int(v) for v in text.split(".")) if text else ()


def _check_machine(record: dict) -> None:
    """Refuse a machine whose glibc or libstdc++ is older than the payload needs."""
    glibc = os.confstr("CS_GNU_LIBC_VERSION").split()[-1]
    if _version(glibc) < _version(record["glibc"]):
        raise ValueError(f"this machine's glibc {glibc} is older than the {record['glibc']} the payload needs")
    ldconfig = shutil.which("ldconfig") or "/sbin/ldconfig"
    if record.get("glibcxx") and os.path.exists(ldconfig):
        listed = subprocess.run([ldconfig, "-p"], capture_output=True, text=True).stdout
        paths = [line.split(" => ")[-1] for line in listed.splitlines() if "libstdc++.so.6 " in line]
        if paths and f"GLIBCXX_{record['glibcxx']}".encode() not in Path(paths[0]).read_bytes():
            raise ValueError(f"{paths[0]} lacks GLIBCXX_{record['glibcxx']}, which the payload needs")


_WRAPPER = """#!/bin/sh
# The factory's relocated Python 3.11 (benchmarks/device_factory.py unpack).  Its home and libraries
# are set here, for it and the processes it starts; the shell's python3 stays the machine's own.
export PYTHONHOME={home} PYTHONNOUSERSITE=1 PYTHONUTF8=1
export LD_LIBRARY_PATH={libs}${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}
exec {python} "$@"
"""
_ENV = """# Source this: python3.11 becomes the factory's relocated Python (bin/python3.11 sets its own
# PYTHONHOME and LD_LIBRARY_PATH), python3 stays the machine's.
export PATH={bin}:"$PATH"
export DEVICE_FACTORY_ENV={dest}
"""
#: run by the relocated Python after unpacking (argv: the tree, the machine's libraries, modules): the
#: modules import (which also writes their bytecode once, not in every worker), and which libraries came
#: from outside the tree
_SMOKE = r"""
import importlib, json, os, sys
dest, allowed, names = sys.argv[1], {n.split(".so")[0] for n in sys.argv[2].split(",")}, sys.argv[3:]
versions = {name: str(getattr(importlib.import_module(name), "__version__", "")) for name in names}
if "bpy" in names:
    versions["bpy"] = sys.modules["bpy"].app.version_string
if "warp" in names:
    sys.modules["warp"].init()
    versions["warp"] += f" ({sys.modules['warp'].get_cuda_device_count()} CUDA devices)"
maps = [line.split() for line in open("/proc/self/maps")]
loaded = {m[5] for m in maps if len(m) >= 6 and ".so" in m[5]}
outside = sorted(p for p in loaded if not os.path.realpath(p).startswith(dest + os.sep)
                 and os.path.basename(p).split(".so")[0] not in allowed)
print(json.dumps({"python": sys.version.split()[0], "prefix": sys.prefix, "versions": versions, "outside": outside}))
"""


def unpack(parts: Path, dest: Path, jobs: int | None = None) -> dict:
    """Check the parts in `parts`, extract the payload into `dest` (in parallel), write
    ``dest/bin/python3.11`` and ``dest/env.sh``, and import every package with the relocated Python.
    Returns the timings and what the import check printed, ``outside`` naming the libraries it loaded
    from the machine besides `DEVICE_LIBS` and `DRIVER_LIBS` (none where the pack is complete, unless
    the machine's GPU stack adds some); a ValueError names a missing or damaged part, an old machine or
    a failed import."""
    parts, dest = Path(parts), Path(dest).resolve()
    timing, started = {}, time.perf_counter()
    staging = dest / ".payload"
    shutil.rmtree(staging, ignore_errors=True)
    unpack_parts(parts, staging)
    timing["join_s"] = time.perf_counter() - started
    record = json.loads((staging / PAYLOAD).read_text())
    _check_machine(record)
    for folder in ("python", "lib", "bin"):
        shutil.rmtree(dest / folder, ignore_errors=True)
    started = time.perf_counter()
    archives = [str(staging / a["name"]) for a in sorted(record["archives"], key=lambda a: -a["bytes"])]
    with ProcessPoolExecutor(max_workers=jobs or os.cpu_count()) as pool:
        files = sum(pool.map(_extract, archives, [str(dest)] * len(archives)))
    timing["extract_s"] = time.perf_counter() - started
    shutil.move(str(staging / PAYLOAD), str(dest / PAYLOAD))
    shutil.rmtree(staging)
    (dest / "bin").mkdir()
    wrapper = dest / "bin" / PYTHON
    wrapper.write_text(_WRAPPER.format(home=shlex.quote(str(dest / "python")),
                                       libs=shlex.quote(f"{dest / 'python' / 'lib'}:{dest / 'lib'}"),
                                       python=shlex.quote(str(dest / "python" / "bin" / PYTHON))))
    wrapper.chmod(0o755)
    (dest / "env.sh").write_text(_ENV.format(bin=shlex.quote(str(dest / "bin")), dest=shlex.quote(str(dest))))
    started = time.perf_counter()
    check = subprocess.run([str(wrapper), "-c", _SMOKE, str(dest), ",".join(DEVICE_LIBS + DRIVER_LIBS), *record["imports"]],
                           capture_output=True, text=True, env={"PATH": os.environ.get("PATH", "/usr/bin:/bin"),
                                                                "HOME": os.environ.get("HOME", "/tmp")})
    timing["import_check_s"] = time.perf_counter() - started
    if check.returncode != 0:
        raise ValueError(f"{wrapper}: the import check failed:\n{check.stderr[-3000:]}")
    return {"files": files, **timing, **json.loads(check.stdout.strip().splitlines()[-1])}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("pack", help="here: the relocatable factory -> OUT/payload, OUT/parts, OUT/calls.json")
    p.add_argument("out", type=Path)
    p.add_argument("--newton", action="store_true", help="also warp-lang and newton (reconstruction's refine)")
    p.add_argument("--part-mb", type=float, default=PART_MB, help="largest part, MiB (default %(default)s)")
    p = sub.add_parser("unpack", help="the device: check the parts, extract, write bin/python3.11 and env.sh")
    p.add_argument("parts", type=Path)
    p.add_argument("dest", type=Path)
    args = parser.parse_args(argv)
    try:
        if args.command == "pack":
            record = pack(args.out, args.newton, args.part_mb)
            plan = calls(args.out)
            (args.out / "calls.json").write_text(json.dumps(plan, indent=1))
            total_in = sum(a["bytes_in"] for a in record["archives"])
            total = sum(a["bytes"] for a in record["archives"])
            print(f"{len(record['archives'])} archives: {total_in / 2**20:.0f} MiB -> {total / 2**20:.0f} MiB "
                  f"(compressed in {record['compress_s']:.0f} s); needs glibc {record['glibc']}, "
                  f"GLIBCXX {record['glibcxx']}")
            for problem in record["problems"]:
                print(f"warning: {problem}", file=sys.stderr)
            for k, call in enumerate(plan):
                print(f"call {k + 1}/{len(plan)}: carry {json.dumps(call['carry'])}\n    {call['command']}")
            print(json.dumps({"archives_mib": round(total / 2**20, 1), "calls": len(plan)}))
        else:
            result = unpack(args.parts, args.dest)
            print(json.dumps(result, indent=1))
            if result["outside"]:
                print(f"note: loaded from this machine: {', '.join(result['outside'])}", file=sys.stderr)
            print(f"ready: . {args.dest / 'env.sh'} then {PYTHON} ...")
    except (ValueError, LookupError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
