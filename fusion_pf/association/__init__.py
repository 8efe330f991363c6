"""Association: the cues' detections to the targets (labels first, then gated nearest prediction)."""

from .base import FRAGMENT_AREA, HANDS, Detection, associate, compatible, fragment, handedness_label, region_area

__all__ = [
    "FRAGMENT_AREA",
    "HANDS",
    "Detection",
    "associate",
    "compatible",
    "fragment",
    "handedness_label",
    "region_area",
]
