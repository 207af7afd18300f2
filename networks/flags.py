"""The networks' CLI flags that set fields of a config dataclass (`TrainConfig`, `SynthConfig`), made
from the fields: a flag's type, its destination and the value it sets come from the field, so a CLI
lists which fields it exposes (with a help text) and never restates them.

    TRAIN_FLAGS = (ConfigFlag("steps", "optimizer steps in total"),
                   ConfigFlag("num_workers", "data loading processes", flag="--workers"),
                   ConfigFlag("augment", "train without augmentation", flag="--no-augment", sets=False))
    add_config_flags(parser, TrainConfig, TRAIN_FLAGS)
    config = config.replace(**config_overrides(args, TRAIN_FLAGS))   # the flags given, by field

The flags shared by several CLIs (the synthesizer's seed, crop jitter and whole-marker crops, which
shards and training must agree on) are defined once here.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing
from dataclasses import dataclass
from typing import Sequence


@dataclass(frozen=True)
class ConfigFlag:
    """The flag of config field `field`: ``--field-name`` unless `flag` names it otherwise (`aliases`:
    other names it also answers to).  A bool field's flag is a switch that sets the field to `sets`
    (``--no-augment`` sets augment False); other fields take a value of the field's type."""

    field: str
    help: str
    flag: str | None = None
    sets: bool | None = None
    metavar: str | None = None
    choices: tuple[str, ...] | None = None
    aliases: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return self.flag or "--" + self.field.replace("_", "-")


def _value_type(cls: type, field: str) -> type:
    """The type of `cls`.`field` without its `None` (``int | None`` -> int)."""
    hint = typing.get_type_hints(cls)[field]
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        hint = next(arg for arg in typing.get_args(hint) if arg is not type(None))
    return hint


def add_config_flags(parser: argparse.ArgumentParser, cls: type, flags: Sequence[ConfigFlag]) -> None:
    """Add each of `flags` (fields of the dataclass `cls`) to `parser`; a flag not given leaves its
    field's attribute None (`config_overrides` drops it).  Each help text ends with the field it sets."""
    fields = {f.name for f in dataclasses.fields(cls)}
    for flag in flags:
        if flag.field not in fields:
            raise ValueError(f"{cls.__name__} has no field {flag.field!r} (flag {flag.name})")
        kind = _value_type(cls, flag.field)
        help = f"{flag.help} ({cls.__name__}.{flag.field})"
        names = (flag.name, *flag.aliases)
        if kind is bool:
            if flag.sets is None:
                raise ValueError(f"{flag.name}: the switch of bool field {flag.field!r} needs the value it sets")
            parser.add_argument(*names, dest=flag.field, action="store_const", const=flag.sets, default=None, help=help)
        elif kind in (int, float, str):
            parser.add_argument(*names, dest=flag.field, type=kind, default=None, metavar=flag.metavar,
                                choices=flag.choices, help=help)
        else:
            raise ValueError(f"{cls.__name__}.{flag.field} is a {kind}: no flag is made for it")


def config_overrides(args: argparse.Namespace, flags: Sequence[ConfigFlag]) -> dict[str, object]:
    """{field: value} of the `flags` given on the command line."""
    return {flag.field: getattr(args, flag.field) for flag in flags if getattr(args, flag.field) is not None}


#: the synthesizer's seed (shards) or the run's (training)
SEED = ConfigFlag("seed", "random seed")
#: crops cut from jittered points: shards and the run that trains on them must agree
CROP_JITTER = ConfigFlag("crop_jitter_px", "cut the crop tasks' crops from five points moved by Gaussian noise of "
                         "this standard deviation, as the Detector cuts them from the localizer's; shards and the "
                         "run that trains on them need the same (default 0: exact points)",
                         flag="--crop-jitter", metavar="PX")
#: the recognizer's crops of whole markers only (the reference's): shards and the run must agree
WHOLE_MARKERS_ONLY = ConfigFlag("recognizer_partial", "recognizer: crops of whole markers only, the reference's "
                                "(default: partial markers with a visible centre too); shards and the run that "
                                "trains on them need the same", flag="--whole-markers-only", sets=False)
