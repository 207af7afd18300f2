"""The trained weights this repository keeps (networks/weights.json): fetched from its history, the
three chained find, identify and locate the markers of a synthesized view of the shirt's IDs."""

import numpy as np

from networks.checkpoint import read_checkpoint
from networks.detector import Detector
from networks.synth import PatternSynthesizer, SynthConfig
from networks.weights import TASKS, fetch, read_manifest, repository_root


def test_the_stored_weights_detect_a_synthesized_view(tmp_path):
    root = repository_root()
    assert set(read_manifest(root)["weights"]) == set(TASKS)  # the repository ships all three
    paths = fetch(tmp_path, root=root)
    detector = Detector.from_checkpoints(paths["localizer"], paths["recognizer"], paths["crosspoints"], device="cpu")
    garment_ids = np.asarray(read_checkpoint(paths["recognizer"])["recognizer_ids"])
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
    assert hit.mean() > 0.9  # seventeenth run: 0.99
    assert right.sum() / hit.sum() > 0.97  # 1.0
    seen = truth.crosspoint_visible[full[right]] & found.crosspoint_visible[nearest[right]]
    error = np.linalg.norm(truth.crosspoints_px[full[right]] - found.crosspoints_px[nearest[right]], axis=-1)[seen]
    assert seen.mean() > 0.9 and np.median(error) < 0.15  # 0.073 px in the image
