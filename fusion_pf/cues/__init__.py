"""Palm cues: paper 003 colour and depth pipelines and skin-colour models (papers 000-002)."""

from .background import BackgroundModel
from .base import SOURCES, CueResult, Measurement
from .colour import ColourCue, colour_cue
from .depth import DepthCue
from .regions import Region, clear_border, dilate, fill_holes, largest_region, region_quality, remove_small
from .roi import Roi, full_roi, make_roi
from .sheet import contact_sheet
from .skeleton import skeleton_cue
from .skin import LabGmmSkin, RgbRuleSkin, RgChromaSkin, SkinCue, grey_world_gains, skin_cue

__all__ = [
    "SOURCES",
    "BackgroundModel",
    "ColourCue",
    "CueResult",
    "DepthCue",
    "LabGmmSkin",
    "Measurement",
    "Region",
    "RgChromaSkin",
    "RgbRuleSkin",
    "Roi",
    "SkinCue",
    "clear_border",
    "colour_cue",
    "contact_sheet",
    "dilate",
    "fill_holes",
    "full_roi",
    "grey_world_gains",
    "largest_region",
    "make_roi",
    "region_quality",
    "remove_small",
    "skeleton_cue",
    "skin_cue",
]
