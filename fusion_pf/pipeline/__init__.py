"""The tracking pipeline: configuration, frames -> cues -> filter -> results, interaction events, and its outputs."""

from .config import DEFAULT_BACKGROUND_K, FILTERS, ROI_PRIORS, TrackConfig
from .events import EVENTS, Event, EventConfig, EventDetector
from .outputs import CSV_COLUMNS, TrackCsv, csv_columns, csv_row, cues_json, estimate_json
from .run import (
    PATCH_MARGIN,
    STATES,
    CueRow,
    TrackResult,
    TrackStats,
    cue_names,
    cue_window,
    extract_cues,
    make_tracker,
    run_filter,
    stages,
    track,
)

__all__ = [
    "CSV_COLUMNS",
    "DEFAULT_BACKGROUND_K",
    "EVENTS",
    "FILTERS",
    "PATCH_MARGIN",
    "ROI_PRIORS",
    "STATES",
    "CueRow",
    "Event",
    "EventConfig",
    "EventDetector",
    "TrackConfig",
    "TrackCsv",
    "TrackResult",
    "TrackStats",
    "csv_columns",
    "csv_row",
    "cue_names",
    "cue_window",
    "cues_json",
    "estimate_json",
    "extract_cues",
    "make_tracker",
    "run_filter",
    "stages",
    "track",
]
