"""Palm cues: paper 003 colour and depth pipelines and skin-colour models (papers 000-002)."""

from .base import SOURCES, CueResult, Measurement

__all__ = ["SOURCES", "CueResult", "Measurement"]
