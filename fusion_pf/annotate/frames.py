"""Frames for the annotator: a small provider protocol and an LRU cache of encoded images.

The server does not care where frames come from: anything with ``len()`` and
``get(index) -> Frame`` is a :class:`FrameProvider`. :class:`ReplayProvider`
adapts a replay source with random access (``drivers.mcap_replay.McapReplay``,
whose ``frame(index)`` decodes one frame). :class:`FrameImages` turns frames into
what the browser shows — the colour image as JPEG or PNG, the depth as a
colour-mapped PNG with transparent holes — and keeps the encoded bytes in an
LRU cache, so moving back and forth between frames does not decode again.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame

from .options import COLOR_FORMATS, ServeOptions


@runtime_checkable
class FrameProvider(Protocol):
    """Random access to the frames of a recording.

    ``len(provider)`` is the number of frames; ``provider.get(i)`` returns frame
    ``i`` for ``0 <= i < len(provider)``. Implementations need not be thread-safe:
    :class:`FrameImages` serialises the calls.
    """

    def __len__(self) -> int:
        """Number of frames."""

    def get(self, index: int) -> Frame:
        """Frame number ``index``."""


class ReplayProvider:
    """A :class:`FrameProvider` over a random-access replay (``McapReplay``).

    Parameters
    ----------
    replay : object
        An opened replay source with ``len()`` and ``frame(index) -> Frame``.
    """

    def __init__(self, replay: Any) -> None:
        self.replay = replay

    def __len__(self) -> int:
        return len(self.replay)

    def get(self, index: int) -> Frame:
        """Frame number ``index`` of the replay."""
        return self.replay.frame(index)


@dataclass(frozen=True)
class FrameMeta:
    """What the server needs to know about a frame without its pixels.

    Attributes
    ----------
    index : int
        Frame index.
    timestamp_ns : int
        Capture time.
    width, height : int
        Colour image size.
    has_depth : bool
        Whether the frame carries a depth image.
    """

    index: int
    timestamp_ns: int
    width: int
    height: int
    has_depth: bool


def depth_to_rgba(depth: np.ndarray) -> np.ndarray:
    """Colour-map a depth image for display: near = red, far = blue, no depth = transparent.

    Parameters
    ----------
    depth : ndarray, shape (H, W), uint16
        Depth in millimetres, 0 = invalid.

    Returns
    -------
    ndarray, shape (H, W, 4), uint8
        BGRA image (OpenCV channel order) using the turbo colour map over the
        2nd to 98th percentile of the valid depths; alpha 0 where depth is 0.
    """
    import cv2

    valid = depth > 0
    out = np.zeros(depth.shape + (4,), np.uint8)
    if not valid.any():
        return out
    lo, hi = np.percentile(depth[valid], [2.0, 98.0])
    hi = max(hi, lo + 1.0)
    scaled = np.clip((hi - depth.astype(np.float32)) / (hi - lo), 0.0, 1.0)
    bgr = cv2.applyColorMap((scaled * 255.0).astype(np.uint8), cv2.COLORMAP_TURBO)
    out[..., :3] = bgr
    out[..., 3] = np.where(valid, 255, 0)
    return out


class FrameImages:
    """Encoded images and metadata of a provider's frames, with an LRU cache.

    Thread-safe: calls into the provider are serialised by a lock, the cache has
    its own lock.

    Parameters
    ----------
    provider : FrameProvider
        Where frames come from.
    color_format : {"jpeg", "png"}
        Encoding of the colour image (JPEG is smaller, PNG lossless).
    jpeg_quality : int
        JPEG quality, 1-100.
    cache_size : int
        Encoded images kept (colour and depth count separately).

    Raises
    ------
    InputError
        On an unknown format, a bad quality or cache size, or an empty provider.
    """

    def __init__(
        self,
        provider: FrameProvider,
        *,
        color_format: str = ServeOptions.image_format,
        jpeg_quality: int = 90,
        cache_size: int = ServeOptions.cache,
    ) -> None:
        if color_format not in COLOR_FORMATS:
            raise InputError(f"color_format must be one of {COLOR_FORMATS}, got {color_format!r}")
        if not 1 <= jpeg_quality <= 100:
            raise InputError(f"jpeg_quality must be in [1, 100], got {jpeg_quality}")
        if cache_size < 1:
            raise InputError(f"cache_size must be >= 1, got {cache_size}")
        if not isinstance(provider, FrameProvider):
            raise InputError(f"provider must have len() and get(index), got {type(provider).__name__}")
        self.provider = provider
        self.n_frames = len(provider)
        if self.n_frames < 1:
            raise InputError("the recording holds no frames to annotate")
        self.color_format = color_format
        self.jpeg_quality = int(jpeg_quality)
        self.cache_size = int(cache_size)
        self._provider_lock = threading.Lock()
        self._cache_lock = threading.Lock()
        self._cache: OrderedDict[tuple[int, str], bytes] = OrderedDict()
        self._meta: dict[int, FrameMeta] = {}
        self.hits = 0
        self.misses = 0

    @property
    def color_mimetype(self) -> str:
        """MIME type of :meth:`color` bytes."""
        return "image/jpeg" if self.color_format == "jpeg" else "image/png"

    def check_index(self, index: int) -> int:
        """Return ``index`` or raise :class:`InputError` when it is not a frame index."""
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < self.n_frames:
            raise InputError(f"frame {index!r} is out of range [0, {self.n_frames})")
        return index

    def _frame(self, index: int) -> Frame:
        self.check_index(index)
        with self._provider_lock:
            frame = self.provider.get(index)
        meta = FrameMeta(index, frame.timestamp_ns, frame.size[0], frame.size[1], frame.depth is not None)
        with self._cache_lock:
            self._meta[index] = meta
        return frame

    def meta(self, index: int) -> FrameMeta:
        """Timestamp, size and depth presence of frame ``index`` (decoded once, then kept)."""
        self.check_index(index)
        with self._cache_lock:
            meta = self._meta.get(index)
        if meta is None:
            self._frame(index)
            meta = self._meta[index]
        return meta

    def _cached(self, key: tuple[int, str]) -> bytes | None:
        with self._cache_lock:
            data = self._cache.get(key)
            if data is not None:
                self._cache.move_to_end(key)
                self.hits += 1
            else:
                self.misses += 1
            return data

    def _store(self, key: tuple[int, str], data: bytes) -> None:
        with self._cache_lock:
            self._cache[key] = data
            self._cache.move_to_end(key)
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)

    def _encode_all(self, index: int) -> dict[str, bytes]:
        import cv2

        frame = self._frame(index)
        bgr = cv2.cvtColor(np.ascontiguousarray(frame.color), cv2.COLOR_RGB2BGR)
        if self.color_format == "jpeg":
            ok, color = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        else:
            ok, color = cv2.imencode(".png", bgr)
        if not ok:
            raise InputError(f"cannot encode frame {index} as {self.color_format}")
        out = {"color": color.tobytes()}
        if frame.depth is not None:
            ok, depth = cv2.imencode(".png", depth_to_rgba(frame.depth))
            if not ok:
                raise InputError(f"cannot encode the depth of frame {index} as PNG")
            out["depth"] = depth.tobytes()
        return out

    def _image(self, index: int, kind: str) -> bytes | None:
        self.check_index(index)
        data = self._cached((index, kind))
        if data is not None:
            return data
        encoded = self._encode_all(index)
        for k, v in encoded.items():
            self._store((index, k), v)
        return encoded.get(kind)

    def color(self, index: int) -> bytes:
        """The colour image of frame ``index``, encoded as :attr:`color_format`."""
        data = self._image(index, "color")
        if data is None:
            raise InputError(f"frame {index} has no colour image")
        return data

    def depth(self, index: int) -> bytes | None:
        """The colour-mapped depth of frame ``index`` as a BGRA PNG, None when it has no depth."""
        if not self.meta(index).has_depth:
            return None
        return self._image(index, "depth")
