"""How a recording is encoded: the options of :class:`~drivers.mcap_record.McapRecorder` as a config.

:class:`EncodingOptions` holds the defaults of the recorder's encoding
arguments (``McapRecorder`` takes them from here) and makes the
``--color-format``, ``--depth-format``, ``--jpeg-quality`` and
``--compression`` flags of every command that writes a recording.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from fusion_pf.options import option, validate

from .mcap_format import COLOR_FORMATS, DEPTH_FORMATS

__all__ = ["COMPRESSION_NAMES", "EncodingOptions"]

#: Chunk compressions of the MCAP writer, by name.
COMPRESSION_NAMES = ("zstd", "lz4", "none")


@dataclass(frozen=True)
class EncodingOptions:
    """Encoding of the colour and depth images and of the MCAP chunks (validated on construction)."""

    color_format: str = option(
        "raw", choices=COLOR_FORMATS, help="colour as RawImage rgb8, or CompressedImage jpeg/png"
    )
    depth_format: str = option(
        "raw", choices=DEPTH_FORMATS, help="depth as RawImage 16UC1, or 16-bit PNG CompressedImage"
    )
    jpeg_quality: int = option(90, kind="int", lo=1, hi=100, metavar="Q", help="JPEG quality")
    compression: str = option("zstd", choices=COMPRESSION_NAMES, help="chunk compression")

    def __post_init__(self) -> None:
        validate(self)

    def recorder_kwargs(self) -> dict[str, object]:
        """The keyword arguments of :class:`~drivers.mcap_record.McapRecorder` (and ``write_recording``)."""
        return dataclasses.asdict(self)
