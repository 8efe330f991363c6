"""The cue contract: a frame (or its arrays) in, one palm measurement (or None) out.

A cue extractor is a pure function or a small class with a ``__call__``. It
takes arrays and keyword-only options, never a device or a file, and returns a
:class:`CueResult`: the measurement (None when nothing qualifies, never NaN or
an exception on degenerate input) plus, on request, its stage images named as
in paper 003 Figures 3-4 (``I_C2`` ... ``I_C9``, ``I_d2`` ... ``I_d10``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np

#: Source names used everywhere (CSV columns, JSON keys, likelihood terms).
SOURCES = ("colour", "depth", "skeleton")


@dataclass(frozen=True, slots=True)
class Measurement:
    """A palm-centre measurement from one source.

    Parameters
    ----------
    source : str
        Name of the source, e.g. ``"colour"``, ``"depth"``, ``"skeleton"``, ``"skin_rg"``.
    u, v : float
        Palm centre in full-frame colour pixels.
    quality : float
        How much the cue trusts itself, in [0, 1] (region compactness, joint
        confidence, ...); robust fusion may weight by it.
    extras : mapping
        Cue-specific values (area in px, ROI, ...), JSON-serialisable.
    """

    source: str
    u: float
    v: float
    quality: float = 1.0
    extras: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "extras", MappingProxyType(dict(self.extras)))

    def __reduce__(self):
        # a mappingproxy cannot be pickled; rebuild from a plain dict (process pools)
        return (Measurement, (self.source, self.u, self.v, self.quality, dict(self.extras)))

    @property
    def z(self) -> np.ndarray:
        """The measurement as a ``(2,)`` float64 array ``[u, v]``."""
        return np.array([self.u, self.v])


@dataclass(frozen=True, slots=True)
class CueResult:
    """What a cue extractor returns.

    Parameters
    ----------
    measurement : Measurement or None
        None when no region qualified.
    stages : mapping of str to ndarray
        Stage images keyed by the paper's names; empty unless requested.
    latency_ns : int
        Wall time the extraction took (``time.perf_counter_ns``).
    """

    measurement: Measurement | None
    stages: Mapping[str, np.ndarray] = field(default_factory=dict)
    latency_ns: int = 0
