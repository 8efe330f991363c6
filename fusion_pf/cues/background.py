"""Background model of the colour and depth pipelines (paper 003 Figs. 3-4, "reference background").

The paper subtracts a blank-scene image recorded before the subject enters.
:class:`BackgroundModel` holds that reference: a colour image ``(H, W, 3)``
uint8 and a depth image ``(H, W)`` uint16 (0 = unknown). Two ways to build it:

* :meth:`BackgroundModel.from_frames` - the per-pixel median of empty-scene
  frames (``fusion-pf cues --background EMPTY.mcap``, or the recording's own
  leading frames flagged ``Frame.background``);
* :meth:`BackgroundModel.running` - a running median over the first ``K``
  frames of the stream (``update(frame)`` until ``ready``), used when no
  empty-scene frame exists; anything that stays still during those K frames
  becomes background.

The depth median ignores invalid pixels (0): a pixel's background depth is the
median of its valid samples, 0 when it never had one.

:class:`AdaptiveBackground` is the model for recordings without an empty
scene: OpenCV's MOG2 background subtractor (a per-pixel Gaussian mixture,
Zivkovic 2004) learns the colour background from the stream and keeps
learning, so slow lighting changes and a hand that was in view at the start
and moved away leave the background; its depth background is the farthest
valid depth seen at each pixel (the scene behind the person).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ..errors import InputError
from ..frame import Frame
from .regions import check_int


def median_color(stack: np.ndarray) -> np.ndarray:
    """Per-pixel median of a ``(K, H, W, 3)`` uint8 stack -> ``(H, W, 3)`` uint8."""
    return np.median(stack, axis=0).round().astype(np.uint8)


def median_valid_depth(stack: np.ndarray) -> np.ndarray:
    """Per-pixel median of the non-zero samples of a ``(K, H, W)`` uint16 stack.

    Zeros are sorted to the end (as ``2**16``), so the valid samples of a pixel
    are the first ``n`` of its sorted column and its median is the mean of
    elements ``(n - 1) // 2`` and ``n // 2``; ``n = 0`` gives 0.
    """
    s = np.sort(np.where(stack == 0, np.uint32(1 << 16), stack.astype(np.uint32)), axis=0)
    n = np.count_nonzero(stack, axis=0)  # valid samples per pixel
    lo = np.take_along_axis(s, np.maximum(n - 1, 0)[None] // 2, axis=0)[0]
    hi = np.take_along_axis(s, np.minimum(n // 2, stack.shape[0] - 1)[None], axis=0)[0]
    med = (lo + hi + 1) // 2  # median of the valid samples, rounded
    return np.where(n > 0, med, 0).astype(np.uint16)


class BackgroundModel:
    """Reference background images for the colour and depth cues.

    Parameters
    ----------
    color : ndarray, shape (H, W, 3), uint8, or None
        Background colour image (RGB); None only inside :meth:`running`
        before its first frame.
    depth : ndarray, shape (H, W), uint16, or None
        Background depth in millimetres (0 = unknown), None without depth.
    learnt : bool
        True when the model was learnt from the tracked stream itself (no
        empty-scene frame): the person is then part of it (the torso is its
        depth), and the depth cue measures the palm against the torso
        (:attr:`~fusion_pf.cues.depth.DepthCue.learnt_lower`).
    """

    def __init__(self, color: np.ndarray | None, depth: np.ndarray | None = None, *, learnt: bool = False) -> None:
        if color is not None:
            if not isinstance(color, np.ndarray) or color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
                raise InputError(
                    f"background colour must be an (H, W, 3) uint8 array, got {getattr(color, 'shape', color)!r}"
                )
        if depth is not None:
            if not isinstance(depth, np.ndarray) or depth.ndim != 2 or depth.dtype != np.uint16:
                raise InputError(
                    f"background depth must be an (H, W) uint16 array, got {getattr(depth, 'shape', depth)!r}"
                )
            if color is not None and depth.shape != color.shape[:2]:
                raise InputError(f"background depth shape {depth.shape} does not match colour {color.shape[:2]}")
        self.color = color
        self.depth = depth
        self.learnt = bool(learnt)
        self._target = 0
        self._colors: list[np.ndarray] = []
        self._depths: list[np.ndarray] = []

    @classmethod
    def from_frames(cls, frames: Iterable[Frame], *, learnt: bool = False) -> "BackgroundModel":
        """The per-pixel median of ``frames`` (at least one): empty-scene frames, or with ``learnt`` the
        stream's own first frames."""
        colors, depths = [], []
        for f in frames:
            colors.append(f.color)
            if f.depth is not None:
                depths.append(f.depth)
        if not colors:
            raise InputError("background needs at least one frame, got none")
        shapes = {c.shape for c in colors}
        if len(shapes) != 1:
            raise InputError(f"background frames must share one size, got {sorted(shapes)}")
        color = median_color(np.stack(colors))
        depth = median_valid_depth(np.stack(depths)) if depths else None
        return cls(color, depth, learnt=learnt)

    @classmethod
    def running(cls, frames: int = 10) -> "BackgroundModel":
        """An empty model that becomes the median of the first ``frames`` frames fed to :meth:`update`."""
        model = cls(None, None, learnt=True)
        model._target = check_int("background frames", frames, 1, 10_000)
        return model

    @property
    def ready(self) -> bool:
        """True once a colour background exists."""
        return self.color is not None

    def update(self, frame: Frame) -> None:
        """Feed one frame to a running model (no-op once it holds ``K`` frames).

        The median is recomputed after every frame, so the model is usable from
        the first frame and final after ``K``.
        """
        if len(self._colors) >= self._target:
            return
        self._colors.append(frame.color)
        if frame.depth is not None:
            self._depths.append(frame.depth)
        self.color = median_color(np.stack(self._colors))
        self.depth = median_valid_depth(np.stack(self._depths)) if self._depths else None


class AdaptiveBackground(BackgroundModel):
    """A background learnt from the stream itself: MOG2 for colour, the farthest depth for depth.

    Parameters
    ----------
    frames : iterable of Frame
        Warm-up frames (at least one), learnt before tracking starts.
    history : int
        MOG2 history in frames (its learning rate is ``1 / history``), 1-100000.
    every : int
        Learn every ``every``-th tracked frame (:meth:`adapt`), 1-1000: MOG2
        costs ~10-20 ms at 1280x720, so the model follows slow changes at a
        fraction of that per frame. MOG2 models every pixel on its own, so the image
        is cut into ``every`` bands of rows, each with its own MOG2: the learnt frame
        teaches one band per tracked frame, in turn, and every frame pays the same
        ~1/``every`` share instead of every ``every``-th frame paying it all (20 ms
        on top of the frame's own work broke a live frame's 33 ms at 30 fps).
    """

    def __init__(self, frames: Iterable[Frame], *, history: int = 300, every: int = 5) -> None:
        import cv2

        self.every = check_int("background every", every, 1, 1000)
        history = check_int("background history", history, 1, 100_000)
        self._seen = 0
        self._bands: list[slice] = []
        self._mogs: list = []
        self._teach: Frame | None = None  # the frame being learnt, band by band
        color = depth = None
        for f in frames:
            if not self._bands:
                edges = np.linspace(0, f.color.shape[0], min(self.every, f.color.shape[0]) + 1).round().astype(int)
                self._bands = [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
                self._mogs = [
                    cv2.createBackgroundSubtractorMOG2(history=history, detectShadows=False) for _ in self._bands
                ]
            for band, mog in zip(self._bands, self._mogs):
                mog.apply(f.color[band])
            if f.depth is not None:
                depth = f.depth.copy() if depth is None else np.maximum(depth, f.depth)
            color = f.color
        if color is None:
            raise InputError("an adaptive background needs at least one frame, got none")
        super().__init__(np.concatenate([mog.getBackgroundImage() for mog in self._mogs]), depth, learnt=True)

    def adapt(self, frame: Frame) -> None:
        """Learn from tracked frames: every ``every``-th one, one band of rows per call in turn (its
        first band at once, the last ``every`` - 1 calls later)."""
        self._seen += 1
        if self._seen % self.every == 0:
            self._teach = frame
        i = self._seen % self.every
        if self._teach is None or i >= len(self._bands):  # fewer rows than ``every``: some calls teach nothing
            return
        band, teach = self._bands[i], self._teach
        self._mogs[i].apply(teach.color[band])
        assert self.color is not None  # set from the warm-up frames
        self.color[band] = self._mogs[i].getBackgroundImage()
        if teach.depth is not None and self.depth is not None:
            np.maximum(self.depth[band], teach.depth[band], out=self.depth[band])  # the farthest surface seen
