"""Build the add-on's zip: one file that Blender installs as an extension and as a legacy add-on.

    python -m blender_addon.package --out out/addon      # -> out/addon/clothcapture-0.1.0.zip

The zip holds one folder named after the manifest's id (``clothcapture/``: the legacy add-on's module
name, so it never shadows the project's own ``blender_addon`` package) with the add-on's files and
``blender_manifest.toml``.  Blender 4.2+ installs it as an extension (Preferences > Get Extensions >
Install from Disk, or ``bpy.ops.extensions.package_install_files``); any version with the legacy
add-on installer (Preferences > Add-ons > Install from Disk, ``bpy.ops.preferences.addon_install``)
reads the same folder and its `bl_info`.  Left out: caches, this script and the README section.
Written atomically with fixed timestamps, so the same sources give the same bytes.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
import zipfile
from pathlib import Path

SOURCE = Path(__file__).resolve().parent
EXCLUDED = {"package.py", "README_SECTION.md"}
_EPOCH = (1980, 1, 1, 0, 0, 0)
_REQUIRED = ("schema_version", "id", "version", "name", "tagline", "maintainer", "type", "blender_version_min",
             "license")


def manifest(source: Path = SOURCE) -> dict:
    """The add-on's ``blender_manifest.toml`` (ValueError naming a missing field)."""
    path = source / "blender_manifest.toml"
    with open(path, "rb") as f:
        data = tomllib.load(f)
    missing = [key for key in _REQUIRED if key not in data]
    if missing:
        raise ValueError(f"{path}: missing {', '.join(missing)}")
    return data


def files(source: Path = SOURCE) -> list[Path]:
    """The add-on's files, relative to `source`, sorted."""
    return sorted(p.relative_to(source) for p in source.rglob("*")
                  if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
                  and str(p.relative_to(source)) not in EXCLUDED)


def build_zip(out_dir: str | Path, source: Path = SOURCE) -> Path:
    """Write ``<out_dir>/<id>-<version>.zip``; returns its path."""
    info = manifest(source)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{info['id']}-{info['version']}.zip"
    tmp = path.with_name(f".{path.name}.part")
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
            for relative in files(source):
                entry = zipfile.ZipInfo(f"{info['id']}/{relative.as_posix()}", date_time=_EPOCH)
                entry.compress_type = zipfile.ZIP_DEFLATED
                entry.external_attr = 0o644 << 16
                archive.writestr(entry, (source / relative).read_bytes())
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m blender_addon.package", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("out/addon"), help="folder of the zip")
    args = parser.parse_args(argv)
    print(build_zip(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
