"""A small two-panel tube with every edge kind, written here so the mesher is tested on its own."""

from assets.garments.sewing import SewingPattern

TUBE = {
    "name": "tube",
    "panels": [
        {
            "name": "front",
            "vertices": [[0, 0], [0.15, 0], [0.15, 0.2], [0, 0.2]],
            "edges": [
                {"name": "hem"},
                {"name": "right", "curve": {"type": "arc", "sagitta": -0.01}},
                {"name": "top", "curve": {"type": "cubic", "control": [[0.1, 0.23], [0.05, 0.17]]}},
                {"name": "left", "curve": {"type": "quadratic", "control": [[-0.01, 0.1]]}},
            ],
            "placement": {"body_part": "torso_front", "rotation_deg": [90, 0, 0], "translation": [-0.075, -0.2, 1.0]},
        },
        {
            "name": "back",
            "vertices": [[0, 0], [0.15, 0], [0.15, 0.2], [0, 0.2]],
            "edges": [
                {"name": "hem"},
                {"name": "right", "curve": {"type": "quadratic", "control": [[0.16, 0.1]]}},
                {"name": "top"},
                {"name": "left", "curve": {"type": "arc", "sagitta": 0.01}},
            ],
            "placement": {"body_part": "torso_back", "rotation_deg": [90, 0, 180], "translation": [0.075, 0.2, 1.0]},
        },
    ],
    "seams": [
        {"a": {"panel": "front", "edge": "right"}, "b": {"panel": "back", "edge": "left"}, "reverse": True},
        {"a": {"panel": "front", "edge": "left"}, "b": {"panel": "back", "edge": "right"}, "reverse": True},
    ],
}


def tube() -> SewingPattern:
    return SewingPattern.from_dict(TUBE, "TUBE")
