"""`networks.flags`: CLI flags made from config dataclass fields set exactly the fields given."""

import argparse

import pytest

from networks.config import TrainConfig
from networks.flags import CROP_JITTER, WHOLE_MARKERS_ONLY, ConfigFlag, add_config_flags, config_overrides
from networks.synth import SynthConfig

FLAGS = (ConfigFlag("steps", "optimizer steps"), ConfigFlag("lr", "peak learning rate"),
         ConfigFlag("num_workers", "data loaders", flag="--workers"),
         ConfigFlag("augment", "no augmentation", flag="--no-augment", sets=False),
         ConfigFlag("recognizer_classes", "classes", choices=("garment", "codebook")), CROP_JITTER, WHOLE_MARKERS_ONLY)


def _parser(cls=TrainConfig, flags=FLAGS) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(exit_on_error=False)
    add_config_flags(parser, cls, flags)
    return parser


def test_the_flags_given_set_their_fields_with_the_field_types():
    args = _parser().parse_args(["--steps", "7", "--lr", "0.5", "--workers", "2", "--no-augment",
                                 "--crop-jitter", "1", "--whole-markers-only"])
    overrides = config_overrides(args, FLAGS)
    assert overrides == {"steps": 7, "lr": 0.5, "num_workers": 2, "augment": False, "crop_jitter_px": 1.0,
                         "recognizer_partial": False}
    assert type(overrides["crop_jitter_px"]) is float and type(overrides["steps"]) is int
    config = TrainConfig("recognizer").replace(**overrides)
    assert (config.steps, config.num_workers, config.augment, config.recognizer_partial) == (7, 2, False, False)


def test_flags_not_given_change_nothing():
    assert config_overrides(_parser().parse_args([]), FLAGS) == {}


def test_a_value_of_another_type_or_choice_is_refused():
    with pytest.raises(argparse.ArgumentError, match="invalid int value"):
        _parser().parse_args(["--steps", "many"])
    with pytest.raises(argparse.ArgumentError, match="invalid choice"):
        _parser().parse_args(["--recognizer-classes", "modules"])


def test_the_same_flag_sets_the_same_field_of_another_config():
    """--crop-jitter and --whole-markers-only mean the same for shards (SynthConfig) as for training."""
    flags = (CROP_JITTER, WHOLE_MARKERS_ONLY)
    overrides = config_overrides(_parser(SynthConfig, flags).parse_args(["--crop-jitter", "1.5", "--whole-markers-only"]),
                                 flags)
    assert SynthConfig().replace(**overrides).crop_geometry().jitter_px == 1.5
    assert "(SynthConfig.crop_jitter_px)" in " ".join(_parser(SynthConfig, flags).format_help().split())


def test_flags_that_name_no_field_or_no_value_are_refused():
    with pytest.raises(ValueError, match="TrainConfig has no field 'stepz'"):
        _parser(flags=(ConfigFlag("stepz", "typo"),))
    with pytest.raises(ValueError, match="bool field 'augment' needs the value it sets"):
        _parser(flags=(ConfigFlag("augment", "a switch without its value"),))
    with pytest.raises(ValueError, match="image_size"):
        _parser(SynthConfig, (ConfigFlag("image_size", "a pair"),))
