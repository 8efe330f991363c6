"""Association: the cues' detections to the targets (labels first, then gated nearest prediction)."""

from .base import HANDS, Detection, associate, compatible, handedness_label

__all__ = ["HANDS", "Detection", "associate", "compatible", "handedness_label"]
