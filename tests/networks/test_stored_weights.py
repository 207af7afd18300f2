"""The trained weights this repository keeps (networks/weights.json): fetched from its history, they
find, identify and locate the markers of a synthesized view: the ID classifier those of the shirt's
IDs, the module reader those of IDs beyond them."""

import numpy as np
import pytest

from networks.checkpoint import read_checkpoint
from networks.detector import Detector
from networks.synth import PatternSynthesizer, SynthConfig
from networks.weights import NETWORKS, fetch, read_manifest, repository_root


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    root = repository_root()
    assert set(read_manifest(root)["weights"]) == set(NETWORKS)  # the repository ships all four
    return fetch(tmp_path_factory.mktemp("weights"), root=root)


@pytest.mark.parametrize("recognizer", ["recognizer", "reader"])
def test_the_stored_weights_detect_a_synthesized_view(stored, recognizer):
    paths = stored
    detector = Detector.from_checkpoints(paths["localizer"], paths[recognizer], paths["crosspoints"], device="cpu")
    trained = np.asarray(read_checkpoint(paths["recognizer"])["recognizer_ids"])
    # the classifier: its own IDs; the reader: a garment's worth of the codebook's last IDs, outside the
    # classifier's and never on a training render (those are the shirt's)
    garment_ids = trained if recognizer == "recognizer" else np.arange(detector.spec.num_ids - len(trained),
                                                                       detector.spec.num_ids)
    assert recognizer == "recognizer" or not np.isin(garment_ids, trained).any()
    # markers of the renders' size, no occluders or fabric edges: about 100 fully visible markers
    config = SynthConfig(image_size=(256, 256), marker_px=(22.0, 28.0), occluders=(0, 0), boundary_probability=0.0,
                         seed=2)
    image, truth = PatternSynthesizer(detector.spec, config, marker_ids=garment_ids).sample(0)
    found = detector([image])[0]

    full = np.flatnonzero(truth.status == 2)
    distance = np.linalg.norm(truth.points_px[full, 0][:, None] - found.points_px[None, :, 0], axis=-1)
    nearest = distance.argmin(axis=1)
    hit = distance[np.arange(len(full)), nearest] < 3.0
    right = hit & (found.marker_id[nearest] == truth.marker_id[full])
    assert len(full) > 50
    assert hit.mean() > 0.9  # 0.99 measured
    assert right.sum() / hit.sum() > 0.97  # 1.0
    seen = truth.crosspoint_visible[full[right]] & found.crosspoint_visible[nearest[right]]
    error = np.linalg.norm(truth.crosspoints_px[full[right]] - found.crosspoints_px[nearest[right]], axis=-1)[seen]
    assert seen.mean() > 0.9 and np.median(error) < 0.15  # 0.073 px in the image
