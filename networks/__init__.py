"""The three networks (Marker Localizer, Marker Recognizer, Crosspoint Localizer) and the Detector.

    from networks import Detector, Detections
    detector = Detector.from_checkpoints("localizer.pt", "recognizer.pt", "crosspoints.pt")
    detections = detector([image])          # image: (H, W, 3) uint8 RGB -> [Detections]

`Detections` (plain numpy, saved as npz) imports without torch, so reconstruction reads cached
detections on machines without it; everything else here needs torch and is imported on first use.
"""

from networks.detections import Detections

__all__ = ["Detections", "Detector", "DetectorConfig"]


def __getattr__(name: str):
    if name in ("Detector", "DetectorConfig"):
        from networks import detector

        return getattr(detector, name)
    raise AttributeError(f"module 'networks' has no attribute {name!r}")
