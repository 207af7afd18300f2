"""The module-reading recognizer: decoding code modules against the codebook (IDs never trained,
all four rotations, a garment's IDs), a few training steps on synthesized crops, and the checkpoint
and Detector plumbing."""

import json

import numpy as np
import pytest
import torch

from assets.pattern import RECOGNIZER_CROP, MarkerTable, PatternSpec, generate_codebook, reference_textures
from networks.checkpoint import load_checkpoint, read_checkpoint, save_checkpoint
from networks.codes import CodeDecoder, module_targets, signed_rotations
from networks.config import TrainConfig
from networks.detector import Detector, DetectorConfig, unwarp_markers
from networks.models import CrosspointLocalizer, MarkerLocalizer, MarkerModuleReader, module_loss
from networks.tasks import build_model, reads_modules
from networks.train import train

#: the default pattern: 4,096 IDs of 12 x 12 modules at least 32 apart under every rotation
SPEC = PatternSpec()
#: a garment printed from IDs above 3000, which no test trains on
GARMENT_IDS = np.arange(3001, 3041)


@pytest.fixture(scope="module")
def codebook():
    return generate_codebook(SPEC)


def _read_modules(crops: np.ndarray) -> torch.Tensor:
    """A hand-made module reader: (B, 96, 96, 3) uint8 recognizer crops -> (B, 144) module logits from
    the mean luminance of each 8 x 8 module's central 4 x 4 pixels, darker than the crop's mid-tone
    meaning filled."""
    n = SPEC.modules_per_side
    side = RECOGNIZER_CROP.size_px // n
    lum = crops.astype(np.float64).mean(axis=-1)
    inner = slice(side // 4, side - side // 4)
    blocks = lum.reshape(len(crops), n, side, n, side)[:, :, inner, :, inner].mean(axis=(2, 4))
    mid = (blocks.min(axis=(1, 2), keepdims=True) + blocks.max(axis=(1, 2), keepdims=True)) / 2
    return torch.as_tensor(((mid - blocks) / 8.0).reshape(len(crops), -1), dtype=torch.float32)


def _hand_made_crops(codebook: np.ndarray, ids: np.ndarray, turns: np.ndarray, seed: int) -> np.ndarray:
    """The reference textures of `ids` in the recognizer's crop under random contrast, brightness and
    noise, each turned `turns` x 90 degrees counter-clockwise (as a crop cut from five points turned so)."""
    rng = np.random.default_rng(seed)
    crops = reference_textures(SPEC, codebook[ids], RECOGNIZER_CROP).astype(np.float64)
    crops = crops * rng.uniform(0.5, 1.2, (len(ids), 1, 1, 1)) + rng.uniform(-40, 40, (len(ids), 1, 1, 1))
    crops = np.clip(crops + rng.normal(0, 12, crops.shape), 0, 255).astype(np.uint8)
    return np.stack([np.rot90(crop, k, axes=(0, 1)) for crop, k in zip(crops, turns)])


def test_hand_made_crops_of_untrained_ids_decode_exactly_under_every_rotation(codebook):
    rng = np.random.default_rng(0)
    ids = np.repeat(GARMENT_IDS, 4)
    turns = np.tile(np.arange(4), len(GARMENT_IDS))
    logits = _read_modules(_hand_made_crops(codebook, ids, turns, seed=1))
    for candidates in (GARMENT_IDS, None):  # the garment's IDs, and the whole codebook
        reading = CodeDecoder(codebook, candidates).decode(logits)
        assert np.array_equal(reading.marker_id.numpy(), ids)
        assert np.array_equal(reading.rotation.numpy(), turns)
        assert (reading.probability.numpy() > 0.99).all() and (reading.margin.numpy() > 0).all()
    decoder = CodeDecoder(codebook, GARMENT_IDS)
    assert np.allclose(decoder.probability_of(logits, ids).numpy(), reading.probability.numpy(), atol=1e-5)
    wrong = GARMENT_IDS[(np.searchsorted(GARMENT_IDS, ids) + 1) % len(GARMENT_IDS)]
    assert (decoder.probability_of(logits, wrong).numpy() < 1e-3).all()
    assert (decoder.probability_of(logits, np.full(len(ids), 5)).numpy() == 0).all()  # not a candidate
    ranked = decoder.ranked(logits[rng.permutation(len(ids))[:6]], k=5)
    assert ranked.shape == (6, 5) and np.isin(ranked.numpy(), GARMENT_IDS).all()


def test_decoding_corrects_up_to_half_the_code_distance_of_wrong_modules(codebook):
    """Module logits of equal confidence, 15 of 144 wrong (the codebook's IDs are at least 32 apart under
    every rotation): the maximum-likelihood ID is the true one, under every rotation."""
    rng = np.random.default_rng(2)
    ids = rng.choice(np.arange(3000, SPEC.num_ids), 64, replace=False)
    turns = rng.integers(0, 4, len(ids))
    signs = signed_rotations(codebook[ids])[np.arange(len(ids)), turns]  # (B, 144) +-1 of what the crops show
    flip = np.argsort(rng.random(signs.shape), axis=1)[:, :15]
    np.put_along_axis(signs, flip, -np.take_along_axis(signs, flip, axis=1), axis=1)
    reading = CodeDecoder(codebook).decode(torch.as_tensor(3.0 * signs))
    assert np.array_equal(reading.marker_id.numpy(), ids) and np.array_equal(reading.rotation.numpy(), turns)
    # score = 0.5 * 3 * (144 - 2 * hamming): the true ID is 15 modules off, any other at least 17
    assert float(reading.margin.min()) >= 0.5 * 3.0 * 2 * 2 - 1e-4


def test_module_targets_are_the_canonical_grids(codebook):
    targets = module_targets(codebook[GARMENT_IDS])
    assert targets.shape == (len(GARMENT_IDS), 144)
    assert np.array_equal(targets.numpy().reshape(-1, 12, 12), codebook[GARMENT_IDS])
    with pytest.raises(ValueError, match="non-empty list of IDs"):
        CodeDecoder(codebook, [SPEC.num_ids])
    with pytest.raises(ValueError, match=r"module logits \(B, 144\)"):
        CodeDecoder(codebook).decode(torch.zeros(2, 100))


def test_module_loss_is_the_bce_of_the_grids():
    logits = torch.tensor([[4.0, -4.0], [0.0, 0.0]])
    grids = torch.tensor([[1.0, 0.0], [1.0, 0.0]])
    expected = (2 * np.log1p(np.exp(-4.0)) + 2 * np.log(2.0)) / 4
    assert float(module_loss(logits, grids)) == pytest.approx(expected, rel=1e-6)


def test_a_module_reader_trains_on_synthesized_crops_and_its_loss_falls(tmp_path):
    """Eight steps on the CPU on synthesized crops of any codebook ID, with a learning rate high enough
    to move a fresh ResNet-50: the module BCE of the last three steps is below that of the first three
    (about 0.75 -> 0.63 at seeds 0 and 1)."""
    spec = PatternSpec(rows=8, cols=8, num_ids=256)
    config = TrainConfig(task="recognizer", recognizer_classes="modules", steps=8, batch_size=8, lr=1e-3,
                         warmup_steps=0, min_lr_ratio=1.0, num_workers=0, log_every=1, val_every=100,
                         val_samples=4, checkpoint_every=100, augment=False, mixed_precision=False)
    result = train(config, "synth", tmp_path / "run", device="cpu", spec=spec, progress=False)
    records = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    losses = [record["module_bce"] for record in records if "module_bce" in record]
    assert len(losses) == 8 and np.mean(losses[-3:]) < np.mean(losses[:3]) - 0.05, losses
    assert result["step"] == 8 and result["val"]["top1"] is not None
    saved = read_checkpoint(tmp_path / "run" / "last.pt")
    assert saved["config"]["recognizer_classes"] == "modules" and saved["recognizer_ids"] is None
    assert saved["model"]["backbone.fc.weight"].shape == (144, 2048)


def test_a_module_reader_checkpoint_round_trips_and_the_detector_decodes_it(tmp_path, codebook):
    """Plumbing, not accuracy (untrained, seeded networks): the checkpoint carries the choice, loads
    back as a module reader, and the Detector reads its IDs through the decoder over the garment's IDs."""
    torch.manual_seed(0)
    reader = MarkerModuleReader(SPEC.modules_per_side)
    config = TrainConfig(task="recognizer", recognizer_classes="modules")
    path = save_checkpoint(tmp_path / "reader.pt", "recognizer", reader, config, SPEC)
    loaded, loaded_config, _ = load_checkpoint(path, expected_task="recognizer", spec=SPEC)
    assert isinstance(loaded, MarkerModuleReader) and reads_modules(loaded)
    assert loaded_config.recognizer_classes == "modules"
    assert all(torch.equal(v, loaded.state_dict()[k]) for k, v in reader.state_dict().items())
    classifier = save_checkpoint(tmp_path / "classifier.pt", "recognizer", build_model("recognizer", SPEC.num_ids),
                                 TrainConfig(task="recognizer", recognizer_classes="codebook"), SPEC)
    data = torch.load(classifier, weights_only=True)
    data["config"]["recognizer_classes"] = "modules"  # a classifier's weights recorded as a module reader's
    torch.save(data, tmp_path / "mislabelled.pt")
    with pytest.raises(ValueError, match="do not fit the recognizer network"):
        load_checkpoint(tmp_path / "mislabelled.pt")

    paths = {"recognizer": path}
    for task, model in (("localizer", MarkerLocalizer()), ("crosspoints", CrosspointLocalizer())):
        paths[task] = save_checkpoint(tmp_path / f"{task}.pt", task, model, TrainConfig(task=task), SPEC)
    table = MarkerTable.build(PatternSpec(rows=5, cols=8), codebook, first_id=int(GARMENT_IDS[0]))
    detector = Detector.from_checkpoints(paths["localizer"], paths["recognizer"], paths["crosspoints"], device="cpu",
                                         tables=[table], config=DetectorConfig(localizer_scale=1.0))
    assert detector.decoder is not None and np.array_equal(detector.decoder.marker_ids, GARMENT_IDS)
    crops = reference_textures(SPEC, codebook[GARMENT_IDS[:6]], RECOGNIZER_CROP)
    image = np.concatenate([np.concatenate(list(crops[:3]), axis=1), np.concatenate(list(crops[3:]), axis=1)])
    corners = np.array([[48, 48], [0, 0], [96, 0], [0, 96], [96, 96]], dtype=np.float32)
    points = np.stack([corners + [96 * (i % 3), 96 * (i // 3)] for i in range(6)])
    ids, probability = detector.recognize([image], np.zeros(6, dtype=np.int64), points)
    with torch.no_grad():
        crops = unwarp_markers([image], np.zeros(6, dtype=np.int64), points, SPEC, RECOGNIZER_CROP)
        logits = detector.recognizer(detector._to_device(crops))
    expected = CodeDecoder(codebook, GARMENT_IDS).decode(logits)
    assert np.array_equal(ids, expected.marker_id.numpy()) and np.isin(ids, GARMENT_IDS).all()
    assert np.allclose(probability, expected.probability.numpy(), atol=1e-5)
    given, given_probability = detector.recognize([image], np.zeros(6, dtype=np.int64), points, ids)
    assert np.array_equal(given, ids) and np.allclose(given_probability, probability, atol=1e-5)
