"""Skin-colour cues: three pixel classifiers and one region step.

Models (each maps an RGB window to a skin mask, uint8 {0, 255}):

* :class:`RgChromaSkin` - paper 000 eq. 5-6: grey-world colour constancy, then
  an rg-chromaticity Gaussian restricted to a rectangle.
* :class:`RgbRuleSkin` - paper 002 eq. 4: the explicit RGB rule of Peer et al.
* :class:`LabGmmSkin` - paper 001: a naive Bayes classifier over CIE-Lab a* and
  b*, each class-conditional density a 1-D Gaussian mixture fitted by EM
  (eq. 16-20); trainable from labelled pixels, saved as a small ``.npz``.

:class:`SkinCue` turns a model's mask into a measurement with the same region
steps as the colour cue (small regions removed, holes filled, dilation,
optional border clearing, largest region -> centroid). Its stage images:

=====  ======================  ==========================================
name   shape, dtype            content
=====  ======================  ==========================================
I_S1   (h, w, 3) uint8         input colour window (RGB)
I_S2   (h, w) uint8            skin score 0-255 (probability x 255)
I_S3   (h, w) uint8 {0, 255}   skin mask (the model's decision)
I_S4   (h, w) uint8 {0, 255}   small regions removed
I_S5   (h, w) uint8 {0, 255}   holes filled
I_S6   (h, w) uint8 {0, 255}   dilated
I_S7   (h, w) uint8 {0, 255}   border cleared (= I_S6 when disabled)
=====  ======================  ==========================================
"""

from __future__ import annotations

import os
import time
from typing import Protocol

import cv2
import numpy as np

from ..errors import InputError
from ..frame import Frame
from ..rng import as_rng
from .base import CueContext, CueResult
from .regions import (
    MIN_AREA_PX,
    check_float,
    check_int,
    clear_border,
    dilate,
    fill_holes,
    measure,
    region_detections,
    remove_small,
)
from .roi import Roi, full_roi


class SkinModel(Protocol):
    """What :class:`SkinCue` needs from a skin model."""

    name: str

    def score(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """Skin score 0-255, uint8 ``(h, w)``, of an RGB window (``frame`` = whole image)."""

    def mask(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """Skin mask, uint8 {0, 255} ``(h, w)``."""


def _check_rgb(name: str, a: np.ndarray) -> None:
    if not isinstance(a, np.ndarray) or a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
        raise InputError(f"{name} must be an (H, W, 3) uint8 RGB array, got {getattr(a, 'shape', a)!r}")


def grey_world_gains(image: np.ndarray) -> np.ndarray:
    """Grey-world gains ``(3,)``: ``k_c = mean(R, G, B) / mean_c`` (paper 000 §II, ref. [6]).

    Scaling each channel by its gain makes the image average grey. A channel
    with mean 0 (or an all-black image) gets gain 1.
    """
    means = np.asarray(cv2.mean(image)[:3], dtype=np.float64)  # per-channel image mean
    grey = means.mean()  # the grey the average should become
    return np.where(means > 0, grey / np.maximum(means, 1e-12), 1.0)


class RgChromaSkin:
    """rg-chromaticity Gaussian skin model with grey-world compensation (paper 000 eq. 5-6).

    Parameters
    ----------
    r_range, g_range : (float, float)
        Rectangle ``(min, max)`` in the rg plane (0-1); the Gaussian's means are
        its centres, ``r_mean = (r_max + r_min) / 2``.
    sigma : float
        Standard deviation in units of the rectangle's half-sides (0.05-10).
        The paper fixes the "variances to a practical value of 0.6"; in absolute
        chromaticity units that would make the Gaussian flat over the
        rectangle, so we read 0.6 relative to the rectangle half-size.
    threshold : float
        Normalised probability (peak = 1) above which a pixel is skin, 0-1.
    grey_world : bool
        Apply grey-world gains computed over the whole frame first.
    """

    name = "skin_rg"

    def __init__(
        self,
        *,
        r_range: tuple[float, float] = (0.40, 0.60),
        g_range: tuple[float, float] = (0.26, 0.36),
        sigma: float = 0.6,
        threshold: float = 0.3,
        grey_world: bool = True,
    ) -> None:
        self.r_range = self._range("r_range", r_range)
        self.g_range = self._range("g_range", g_range)
        self.sigma = check_float("rg sigma", sigma, 0.05, 10.0)
        self.threshold = check_float("rg threshold", threshold, 0.0, 1.0)
        self.grey_world = bool(grey_world)

    @staticmethod
    def _range(name: str, value: tuple[float, float]) -> tuple[float, float]:
        try:
            lo, hi = (float(x) for x in value)
        except (TypeError, ValueError):
            raise InputError(f"{name} must be a pair (min, max) in [0, 1], got {value!r}") from None
        if not (0.0 <= lo < hi <= 1.0):
            raise InputError(f"{name} must satisfy 0 <= min < max <= 1, got {value!r}")
        return lo, hi

    def probability(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """Normalised eq. 6 probability in [0, 1], float32 ``(h, w)`` (0 outside the rectangle)."""
        _check_rgb("skin window", window)
        rgb = window.astype(np.float32)
        if self.grey_world:
            rgb *= grey_world_gains(window if frame is None else frame).astype(np.float32)  # grey-world
        s = rgb.sum(axis=2)
        s[s <= 0] = 1.0  # black pixels: r = g = 0, outside any skin rectangle
        r = rgb[..., 0] / s  # eq. 5: r = R / (R + G + B)
        g = rgb[..., 1] / s  # eq. 5: g = G / (R + G + B)
        (r0, r1), (g0, g1) = self.r_range, self.g_range
        rm, gm = (r0 + r1) / 2, (g0 + g1) / 2  # rectangle centres = Gaussian means
        sr, sg = self.sigma * (r1 - r0) / 2, self.sigma * (g1 - g0) / 2
        f = np.exp(-((r - rm) ** 2) / (2 * sr * sr) - ((g - gm) ** 2) / (2 * sg * sg))  # eq. 6 / its peak
        inside = (r >= r0) & (r <= r1) & (g >= g0) & (g <= g1)  # only the modelled rectangle
        return np.where(inside, f, 0.0).astype(np.float32)

    def score(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """Eq. 6 probability scaled to 0-255 (as the paper displays it)."""
        return np.round(self.probability(window, frame) * 255).astype(np.uint8)

    def mask(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """Pixels whose normalised probability is at least ``threshold``."""
        p = self.probability(window, frame)
        return np.where((p >= self.threshold) & (p > 0), np.uint8(255), np.uint8(0))


class RgbRuleSkin:
    """Explicit RGB skin rule (paper 002 eq. 4, after Peer et al.)."""

    name = "skin_rgb"

    def mask(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """Eq. 4: R>45, G>40, B>20, max-min>15, |R-G|>15, R>G, R>B."""
        _check_rgb("skin window", window)
        R, G, B = window[..., 0], window[..., 1], window[..., 2]
        spread = np.maximum(np.maximum(R, G), B) - np.minimum(np.minimum(R, G), B)  # max - min, no overflow
        ok = (R > 45) & (G > 40) & (B > 20)  # bright enough in every channel
        ok &= (spread > 15) & (cv2.absdiff(R, G) > 15)  # saturated, red distinct from green
        ok &= (R > G) & (R > B)  # red dominant
        return np.where(ok, np.uint8(255), np.uint8(0))

    def score(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """The rule is binary: the score is the mask."""
        return self.mask(window, frame)


def lab_ab(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV 8-bit CIE-Lab a* and b* of RGB uint8 pixels (``a* + 128``, ``b* + 128``)."""
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab)
    return lab[..., 1], lab[..., 2]


def _log_gauss(x: np.ndarray, mean: np.ndarray, var: np.ndarray) -> np.ndarray:
    """log N(x; mean, var) for x ``(n, 1)`` against k components -> ``(n, k)`` (paper 001 eq. 19)."""
    return -0.5 * (np.log(2 * np.pi * var) + (x - mean) ** 2 / var)


def fit_gmm_1d(
    x: np.ndarray, k: int, *, rng: np.random.Generator, max_iter: int = 100, tol: float = 1e-6, min_var: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EM fit of a 1-D k-component Gaussian mixture (paper 001 eq. 16-21).

    Returns ``(means, variances, weights)``, each ``(k,)``. Initial means are k
    distinct samples drawn with ``rng``; variances start at the data variance;
    iteration stops after ``max_iter`` steps or when the mean log-likelihood
    (eq. 21) improves by less than ``tol``. Variances are floored at
    ``min_var`` (the 8-bit quantisation step).
    """
    x = np.asarray(x, dtype=np.float64)[:, None]
    uniq = np.unique(x)
    k = min(k, uniq.size)
    mean = np.sort(rng.choice(uniq, size=k, replace=False))
    var = np.full(k, max(float(x.var()), min_var))
    weight = np.full(k, 1.0 / k)
    last = -np.inf
    for _ in range(max_iter):
        logp = _log_gauss(x, mean, var) + np.log(weight)  # log f(x; mu, sigma) p for each component
        norm = np.logaddexp.reduce(logp, axis=1, keepdims=True)
        resp = np.exp(logp - norm)  # eq. 20: membership w of each sample
        nk = resp.sum(axis=0) + 1e-12
        mean = (resp * x).sum(axis=0) / nk  # eq. 16: weighted mean
        var = np.maximum((resp * (x - mean) ** 2).sum(axis=0) / nk, min_var)  # eq. 17: weighted variance
        weight = nk / nk.sum()  # eq. 18: component probability
        ll = float(norm.mean())  # eq. 21: log-likelihood (per sample)
        if ll - last < tol:
            break
        last = ll
    return mean, var, weight


class LabGmmSkin:
    """Naive Bayes skin classifier over CIE-Lab a*, b* with EM Gaussian mixtures (paper 001).

    ``p(x | c) = p_a(a* | c) p_b(b* | c)`` (naive independence) with each
    factor a 1-D mixture; a pixel is skin when the MAP rule (eq. 14)
    ``log p(x | skin) + log P(skin) > log p(x | non-skin) + log P(non-skin)``
    holds. Prediction uses two 256-entry log-likelihood-ratio tables.

    Parameters
    ----------
    means, variances, weights : ndarray, shape (2, 2, k)
        Indexed ``[class, feature, component]``, class 0 = non-skin,
        1 = skin, feature 0 = a*, 1 = b* (OpenCV 8-bit units).
    log_prior : ndarray, shape (2,)
        ``log P(non-skin), log P(skin)``.
    """

    name = "skin_lab"

    def __init__(self, means: np.ndarray, variances: np.ndarray, weights: np.ndarray, log_prior: np.ndarray) -> None:
        means, variances, weights, log_prior = (
            np.asarray(a, dtype=np.float64) for a in (means, variances, weights, log_prior)
        )
        if (
            means.ndim != 3
            or means.shape[:2] != (2, 2)
            or variances.shape != means.shape
            or weights.shape != means.shape
        ):
            raise InputError(
                f"LabGmmSkin parameters must be (2, 2, k) arrays, got {means.shape}, {variances.shape}, {weights.shape}"
            )
        if log_prior.shape != (2,):
            raise InputError(f"LabGmmSkin log_prior must have shape (2,), got {log_prior.shape}")
        if (
            not all(np.isfinite(a).all() for a in (means, variances, weights, log_prior))
            or (variances <= 0).any()
            or (weights < 0).any()
        ):
            raise InputError("LabGmmSkin parameters must be finite with positive variances and non-negative weights")
        self.means, self.variances, self.weights, self.log_prior = means, variances, weights, log_prior
        levels = np.arange(256, dtype=np.float64)[:, None]
        logpdf = np.empty((2, 2, 256))
        for c in range(2):
            for f in range(2):
                comp = _log_gauss(levels, means[c, f], variances[c, f]) + np.log(np.maximum(weights[c, f], 1e-300))
                logpdf[c, f] = np.logaddexp.reduce(comp, axis=1)  # log of the mixture density at each level
        self._lut_a = (logpdf[1, 0] - logpdf[0, 0]).astype(np.float32)  # log p(a*|skin) - log p(a*|non)
        self._lut_b = (logpdf[1, 1] - logpdf[0, 1]).astype(np.float32)  # log p(b*|skin) - log p(b*|non)
        self._bias = np.float32(log_prior[1] - log_prior[0])  # log P(skin) - log P(non-skin)

    @classmethod
    def fit(
        cls,
        pixels: np.ndarray,
        labels: np.ndarray,
        *,
        components: int = 3,
        rng: np.random.Generator | int | None = 0,
        max_samples: int = 20_000,
        max_iter: int = 100,
    ) -> "LabGmmSkin":
        """Fit from labelled RGB pixels.

        Parameters
        ----------
        pixels : ndarray, shape (N, 3), uint8
            RGB pixels (e.g. ``frame.color[mask_known]``).
        labels : ndarray, shape (N,), bool
            True for skin. Both classes must be present.
        components : int
            Mixture components per class and feature, 1-10.
        rng : Generator, int or None
            Randomness of the subsampling and EM initialisation.
        max_samples : int
            At most this many pixels per class are used (random subset), 10-10**7.
        max_iter : int
            EM iteration limit, 1-10000.
        """
        components = check_int("components", components, 1, 10)
        max_samples = check_int("max_samples", max_samples, 10, 10_000_000)
        max_iter = check_int("max_iter", max_iter, 1, 10_000)
        pixels = np.asarray(pixels)
        labels = np.asarray(labels, dtype=bool)
        if pixels.ndim != 2 or pixels.shape[1] != 3 or pixels.dtype != np.uint8:
            raise InputError(f"pixels must be an (N, 3) uint8 array, got {pixels.shape} {pixels.dtype}")
        if labels.shape != (pixels.shape[0],):
            raise InputError(f"labels must have shape ({pixels.shape[0]},), got {labels.shape}")
        counts = np.array([np.count_nonzero(~labels), np.count_nonzero(labels)])
        if (counts == 0).any():
            raise InputError(f"need skin and non-skin pixels, got {counts[1]} skin and {counts[0]} non-skin")
        gen = as_rng(rng)
        a, b = lab_ab(pixels[:, None, :])
        feats = np.stack([a[:, 0], b[:, 0]], axis=1)
        means = np.zeros((2, 2, components))
        variances = np.ones((2, 2, components))
        weights = np.zeros((2, 2, components))
        for c, sel in enumerate((~labels, labels)):
            idx = np.flatnonzero(sel)
            if idx.size > max_samples:
                idx = gen.choice(idx, size=max_samples, replace=False)
            for f in range(2):
                m, v, w = fit_gmm_1d(feats[idx, f], components, rng=gen, max_iter=max_iter)
                means[c, f, : m.size], variances[c, f, : m.size], weights[c, f, : m.size] = m, v, w
        log_prior = np.log(counts / counts.sum())  # class priors from the label frequencies (MAP, eq. 14)
        return cls(means, variances, weights, log_prior)

    def log_odds(self, window: np.ndarray) -> np.ndarray:
        """``log P(skin | x) - log P(non-skin | x)``, float32 ``(h, w)``."""
        _check_rgb("skin window", window)
        a, b = lab_ab(window)
        return self._lut_a[a] + self._lut_b[b] + self._bias  # naive Bayes: sum of per-feature log ratios

    def score(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """Posterior ``P(skin | x)`` scaled to 0-255."""
        p = 1.0 / (1.0 + np.exp(-np.clip(self.log_odds(window), -50, 50)))
        return np.round(p * 255).astype(np.uint8)

    def mask(self, window: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """MAP decision (paper 001 eq. 14)."""
        return np.where(self.log_odds(window) > 0, np.uint8(255), np.uint8(0))

    def save(self, path: str | os.PathLike) -> None:
        """Write the model as an ``.npz`` of plain arrays (no pickle)."""
        np.savez(
            path,
            kind=np.array("lab_gmm_naive_bayes"),
            version=np.array(1),
            means=self.means,
            variances=self.variances,
            weights=self.weights,
            log_prior=self.log_prior,
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> "LabGmmSkin":
        """Read a model written by :meth:`save`; InputError when the file is not one."""
        name = os.fspath(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                kind = str(z["kind"])
                arrays = [z[k] for k in ("means", "variances", "weights", "log_prior")]
        except (KeyError, ValueError, EOFError) as exc:
            raise InputError(f"{name} is not a LabGmmSkin .npz model: {exc}") from None
        if kind != "lab_gmm_naive_bayes":
            raise InputError(f"{name} is not a LabGmmSkin model (kind {kind!r})")
        return cls(*arrays)


class SkinCue:
    """Skin mask -> palm measurement (region steps of paper 003 Fig. 3 on a skin mask).

    Parameters
    ----------
    model : RgChromaSkin, RgbRuleSkin or LabGmmSkin
        The pixel classifier.
    min_area : int
        Regions smaller than this (px) are removed, 0-100000.
    dilate : int
        Dilation disc radius in px, 0-50.
    clear_border : bool
        Remove regions touching the window border (off by default: a bare
        forearm entering the window would otherwise take the hand with it).
    core : bool
        Measure a region's core centre (:func:`~fusion_pf.cues.regions.core_centre`,
        as the colour cue does: on the palm, not toward the elbow of a bare
        forearm) instead of its centroid.
    source : str, optional
        Measurement source name; the model's ``name`` by default.
    """

    def __init__(
        self,
        model: SkinModel,
        *,
        min_area: int = MIN_AREA_PX,
        dilate: int = 1,
        clear_border: bool = False,
        core: bool = True,
        source: str | None = None,
    ) -> None:
        if not (hasattr(model, "mask") and hasattr(model, "score")):
            raise InputError(f"skin model must have mask() and score(), got {type(model).__name__}")
        self.model = model
        self.min_area = check_int("skin min_area", min_area, 0, 100_000)
        self.dilate = check_int("skin dilate radius", dilate, 0, 50)
        self.clear_border = bool(clear_border)
        self.core = bool(core)
        self.source = str(source) if source is not None else model.name

    #: Frame parts the cue reads (:data:`~fusion_pf.cues.base.NEEDS`).
    needs = frozenset({"color"})

    @property
    def name(self) -> str:
        """Source name of the measurements."""
        return self.source

    def reset(self) -> None:
        """Nothing to forget: the skin cue has no state."""

    def measure(self, frame: Frame, ctx: CueContext) -> CueResult:
        """The :class:`~fusion_pf.cues.base.Cue` form: skin in ``frame``'s colour image."""
        return self(
            frame.color, roi=ctx.roi, stages=ctx.stages, near=ctx.prior, candidates=ctx.candidates, parts=ctx.parts
        )

    def __call__(
        self,
        color: np.ndarray,
        *,
        roi: Roi | None = None,
        stages: bool = False,
        near: tuple[float, float] | None = None,
        candidates: bool = False,
        parts: tuple[tuple[float, float], ...] = (),
    ) -> CueResult:
        """Segment skin in ``color`` (inside ``roi``) and measure the skin region nearest ``near`` (else the largest).

        With ``candidates`` every region is also returned (``CueResult.candidates``,
        several targets: the association picks; joined hands' ``parts`` as in
        :func:`~fusion_pf.cues.regions.region_detections`).
        """
        t0 = time.perf_counter_ns()
        _check_rgb("colour", color)
        h, w = color.shape[:2]
        roi = full_roi(w, h) if roi is None else roi
        out: dict[str, np.ndarray] = {}
        if roi.empty:
            return CueResult(None, out, time.perf_counter_ns() - t0)
        s1 = roi.crop(color)
        s3 = self.model.mask(s1, color)  # the model's skin decision
        s4 = remove_small(s3, self.min_area)  # small regions removed
        s5 = fill_holes(s4)  # holes filled
        s6 = dilate(s5, self.dilate)  # dilation
        s7 = clear_border(s6) if self.clear_border else s6  # border cleared
        m = measure(
            s7,
            roi.offset,
            self.source,
            palm_area=roi.palm_area,
            min_area=self.min_area,
            extras={"roi": roi.as_list()},
            near=near,
            core=self.core,
        )
        found = (
            region_detections(
                s7,
                roi.offset,
                self.source,
                palm_area=roi.palm_area,
                min_area=self.min_area,
                extras={"roi": roi.as_list()},
                parts=parts,
                core=self.core,
            )
            if candidates
            else ()
        )
        if stages:
            out = {
                "I_S1": s1.copy(),
                "I_S2": self.model.score(s1, color),
                "I_S3": s3,
                "I_S4": s4,
                "I_S5": s5,
                "I_S6": s6,
                "I_S7": s7,
            }
        return CueResult(m, out, time.perf_counter_ns() - t0, found)


def skin_cue(
    color: np.ndarray, model: SkinModel, *, roi: Roi | None = None, stages: bool = False, **options: object
) -> CueResult:
    """Functional form of :class:`SkinCue`: ``SkinCue(model, **options)(color, ...)``."""
    return SkinCue(model, **options)(color, roi=roi, stages=stages)  # type: ignore[arg-type]
