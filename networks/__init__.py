"""The three networks (Marker Localizer, Marker Recognizer, Crosspoint Localizer) and the Detector.

    import networks
    detector = networks.Detector.from_checkpoints("localizer.pt", "recognizer.pt", "crosspoints.pt")
    detections = detector([image])          # image: (H, W, 3) uint8 RGB -> [networks.Detections]

    config = networks.TrainConfig("localizer", steps=20_000)
    networks.train_network(config, "out/ds", "runs/loc")               # a run folder: best.pt, last.pt
    networks.evaluate_network("runs/loc/best.pt", "out/ds", split="test")  # metrics of one network

The public API, by what a user does:

* detect: `Detector` (images -> `Detections`), `DetectorConfig` (its options), `Detections` (plain
  numpy, saved as npz), `DetectorResult` (what `Detector.detect` returns: the detections with the
  localizer scale of each image and the seconds of each stage; a Detector keeps nothing of a call).
* train: `TrainConfig` (one run's numbers), `train_network` (a run folder), `load_recipe` (a recipe file's
  networks and data), `TASKS` (the networks' names: localizer, recognizer, crosspoints).
* synthesize: `SynthConfig` and `PatternSynthesizer` (procedural samples with exact ground truth),
  `write_shards` (pre-synthesized samples for training).
* evaluate: `evaluate_network` (one network on a dataset split or a shard folder), `evaluate_chain`
  and `load_detector` (the Detector, its three networks chained, on a dataset split).
* checkpoints: `load_checkpoint` (model, config, record), `slim_checkpoint` (weights only),
  `fetch_weights` (the stored networks from the repository's history).

Each CLI is a module: ``python -m networks.train``, ``networks.shards write``, ``networks.evaluate``,
``networks.evaluate_detector``, ``networks.checkpoint slim``, ``networks.weights fetch``.

`import networks` is cheap and needs no torch: `Detections` is imported with the package (reconstruction
reads cached detections on machines without torch); every other name is imported on first use.
Names that would be those of the package's modules (`networks.train`, `networks.evaluate`,
`networks.evaluate_detector`: the CLIs) are exported as `train_network`, `evaluate_network` and
`evaluate_chain`, so that importing a module never replaces a function of this API.
"""

from assets.lazy import lazy_api

from networks.detections import Detections

#: public name -> (module, name in it); imported on first use (`__getattr__`)
_LAZY = {
    "Detector": ("networks.detector", "Detector"),
    "DetectorConfig": ("networks.detector", "DetectorConfig"),
    "DetectorResult": ("networks.detector", "DetectorResult"),
    "TASKS": ("networks.config", "TASKS"),
    "TrainConfig": ("networks.config", "TrainConfig"),
    "train_network": ("networks.train", "train"),
    "load_recipe": ("networks.recipe", "load_recipe"),
    "SynthConfig": ("networks.synth", "SynthConfig"),
    "PatternSynthesizer": ("networks.synth", "PatternSynthesizer"),
    "write_shards": ("networks.shards", "write_shards"),
    "evaluate_network": ("networks.evaluate", "evaluate"),
    "evaluate_chain": ("networks.evaluate_detector", "evaluate_detector"),
    "load_detector": ("networks.evaluate_detector", "load_detector"),
    "load_checkpoint": ("networks.checkpoint", "load_checkpoint"),
    "slim_checkpoint": ("networks.checkpoint", "slim_checkpoint"),
    "fetch_weights": ("networks.weights", "fetch"),
}

__all__ = ["Detections", *_LAZY]


__getattr__, __dir__ = lazy_api(__name__, _LAZY)
