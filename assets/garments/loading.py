"""Garments by name or file: the one place a CLI argument like ``shirt`` or ``my_pattern.json``
becomes a sewing pattern or a template."""

from __future__ import annotations

from pathlib import Path

from assets.fileio import load_json
from assets.garments.defaults import DEFAULT_GARMENTS, default_pattern
from assets.garments.garmentcode import garmentcode_from_dict
from assets.garments.sewing import MAX_PANEL_M, SewingPattern
from assets.garments.template import Template


def load_pattern(name_or_path: str, max_panel_m: float = MAX_PANEL_M) -> SewingPattern:
    """A default garment by name, or a JSON file in our format or GarmentCode's; no panel of a file
    may reach more than `max_panel_m` across (`assets.garments.sewing.check_panel_size`)."""
    if name_or_path in DEFAULT_GARMENTS:
        return default_pattern(name_or_path)
    path = Path(name_or_path)
    if not path.exists():
        raise ValueError(f"'{name_or_path}' is neither a default garment ({', '.join(DEFAULT_GARMENTS)}) nor a file")
    data = load_json(path)
    if isinstance(data, dict) and "pattern" in data:
        return garmentcode_from_dict(data, str(path), max_panel_m=max_panel_m)
    return SewingPattern.from_dict(data, str(path), max_panel_m)


def load_template(garment: str | Path, dpi: float | None = None) -> Template:
    """A default garment name, a pattern JSON (ours or GarmentCode) or a saved template `.npz` (a str
    or a Path); its sheet laid out at `dpi` (default: a saved template's own, else `Template.build`'s)."""
    garment = str(garment)
    if garment.endswith(".npz"):
        template = Template.load(garment)
        return template if dpi is None else Template.build(template.pattern, template.layout.spec, dpi)
    pattern = load_pattern(garment)
    return Template.build(pattern) if dpi is None else Template.build(pattern, dpi=dpi)
