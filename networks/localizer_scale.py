"""The automatic localizer scale (`networks.DetectorConfig.localizer_scale` None): the scale at which the
Marker Localizer sees each image, chosen from the markers that passes at a few scales find.

The localizer knows markers of about 10 to 32 px in its input (trained on 16-32 px).  Outside that it
does not fail quietly: markers of 40 px and more are found several times each, at sizes it knows, so
neither the number of detections nor their sizes tell a wrong scale; their confidence does
(docs/journal/2026-11-29-auto-localizer-scale.md).  Hence the search (`search_scales`): passes at
`AUTO_LEVELS`, coarsest (cheapest) first, until one `sees_markers`; their median side gives the
scale that makes it the target size (`networks.homography.auto_localizer_scale`), where the image
is localized again and checked the same way.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from networks.homography import AUTO_MIN_MARKERS, auto_localizer_scale

#: what a localizer pass gives per image: points_px (N, 5, 2) float32 in the image's pixels, presence (N,)
Found = tuple[np.ndarray, np.ndarray]

#: the scales at which the automatic localizer scale looks for markers, coarsest first: a factor of 2
#: apart, so that a marker of 11 to 350 px is 11 to 22 px at one of them (the localizer, trained on
#: 16-32 px, finds markers with confidence from about 10 px), and each costs a quarter of the next
AUTO_LEVELS = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0)
#: the coarsest level an image is looked at shows it at least this many pixels along its longest side
#: (a marker spans at most half of the image)
AUTO_COARSEST_SIDE_PX = 64
#: a pass sees the markers when it finds at least `networks.homography.AUTO_MIN_MARKERS` whose median
#: presence probability is at least this: markers of 9-25 px in the localizer's input gave medians of
#: 0.87-1.0, markers of 3-6 px or of 40 px and more 0.62-0.78 (or nothing)
AUTO_MIN_PRESENCE = 0.85
#: a chosen scale this close to that of the pass that measured it (relative) keeps that pass's markers
AUTO_KEEP_RELATIVE = 0.1


def sees_markers(presence: np.ndarray) -> bool:
    """Whether a localizer pass that found markers of these presence probabilities (N,) saw the
    image's markers at a size it knows (`AUTO_MIN_PRESENCE`)."""
    return len(presence) >= AUTO_MIN_MARKERS and float(np.median(presence)) >= AUTO_MIN_PRESENCE


def auto_levels(image_size: tuple[int, int]) -> list[float]:
    """The `AUTO_LEVELS` at which an image of (H, W) is looked at: those showing its longest side at
    `AUTO_COARSEST_SIDE_PX` or more, and 1 always."""
    side = max(image_size)
    return [level for level in AUTO_LEVELS if level == 1.0 or side * level >= AUTO_COARSEST_SIDE_PX]


def search_scales(images: Sequence[np.ndarray], localize_at: Callable[[list[np.ndarray], list[float]], list[Found]],
                  marker_px: float) -> tuple[list[Found], list[float]]:
    """(per image, the markers of the pass at its chosen scale; per image, that scale).

    localize_at(images, scales): the localizer's markers of each image seen at its scale (one batch of
    passes, `networks.detector.Detector._localize`).  Each image is looked at at its `auto_levels`,
    coarsest first; at the first pass that `sees_markers`, their median side gives the scale that makes
    it `marker_px` (`auto_localizer_scale`), and the image is localized there (that pass's markers kept
    when the scale is within `AUTO_KEEP_RELATIVE` of its).  A scale whose pass does not see the
    markers (a measure thrown by a few large markers) lets the search go on at the next level.  An
    image no pass convinces keeps the pass of the most confident markers (the highest median presence;
    the finest level when none found any).  The images of one level are localized in one call.
    """
    located: list[Found | None] = [None] * len(images)
    scales: list[float | None] = [None] * len(images)
    levels = [auto_levels(image.shape[:2]) for image in images]
    best: list[tuple[float, float, Found] | None] = [None] * len(images)  # (median presence, scale, found)

    def consider(i: int, scale: float, found: Found) -> None:
        presence = float(np.median(found[1])) if len(found[1]) else -1.0  # -1: none found, the finest kept
        if best[i] is None or presence > best[i][0] or presence == best[i][0] == -1.0:
            best[i] = (presence, scale, found)

    for level in AUTO_LEVELS:
        todo = [i for i in range(len(images)) if scales[i] is None and level in levels[i]]
        again = []
        for i, found in zip(todo, localize_at([images[i] for i in todo], [level] * len(todo))):
            consider(i, level, found)
            if not sees_markers(found[1]):
                continue
            chosen = auto_localizer_scale(found[0], level, marker_px)
            if abs(chosen / level - 1) <= AUTO_KEEP_RELATIVE:
                located[i], scales[i] = found, level
            else:
                again.append((i, chosen))
        for (i, chosen), found in zip(again, localize_at([images[i] for i, _ in again], [c for _, c in again])):
            consider(i, chosen, found)
            if sees_markers(found[1]):
                located[i], scales[i] = found, chosen
    for i in range(len(images)):
        if scales[i] is None:
            _, scales[i], located[i] = best[i]
    return located, scales
