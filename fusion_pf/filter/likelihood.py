"""Per-source and joint likelihoods of the particles (paper 003 §3.6, eqs. 5-7), in log space.

Paper pipeline for one frame: squared distance of every particle to the cue
(eq. 5), a Gaussian likelihood per source with that source's noise (eq. 6, with
``rho = sigma^2``), each source normalised into (0, 1] (step 3; here by its
maximum, i.e. subtracting the max in log space), and the joint likelihood as the
element-wise product over the available sources (eq. 7) -- a sum of log arrays.
A source that gave no measurement in a frame is simply absent from the sum.
For the Gaussian likelihood the product of eq. 7 is one Gaussian around the
precision-weighted cue mean, so :class:`JointLikelihood` evaluates it in a
single pass over the particles whatever the number of sources.

Beyond the paper, the *robust* likelihood of one source is the mixture
``(1 - eps) N2(d; sigma_eff) + eps / A``: a 2-D Gaussian density of the particle
position around the cue plus a uniform "the cue is lying" density over an area
``A`` px^2 (default the 1280 x 800 frame). A cue far from every particle then
costs a bounded factor instead of dragging the cloud towards it. With
``use_quality`` the Gaussian widens as the cue trusts itself less:
``sigma_eff = sigma / sqrt(max(quality, q_min))`` (quality 1 -> sigma, 0.25 ->
2 sigma, never more than ``sigma / sqrt(q_min)``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement

__all__ = [
    "DEFAULT_NOISE_PX",
    "DEFAULT_OUTLIER_AREA_PX2",
    "LIKELIHOODS",
    "MAX_COORD_PX",
    "MIN_OUTLIER_PROB",
    "MIN_QUALITY",
    "PROBABILITY_QUALITY",
    "UNDERFLOW_LOG",
    "JointLikelihood",
    "check_noise_px",
    "effective_sigma",
    "gaussian_loglik",
    "quality_sigma",
    "robust_loglik",
    "squared_distance",
]

#: Default measurement noise per source (px, 1 sigma per axis): the one
#: definition, used by the filters and ``fusion-pf track``. Colour, depth and
#: skeleton were tuned for the robust particle filter on synthetic scenes seeds
#: 2 and 4 (320 x 200, 200 person frames, filter seed 1, ROI on the skeleton
#: joint), over colour {5, 8, 12} x depth {3, 4, 6} x skeleton {20, 40}, with
#: and without the paper's added 4 px cue noise; the sample recording (seed 0)
#: was not used. The colour cue is trusted least of the image cues because a
#: bare forearm pulls its centroid 5-7 px toward the elbow; the skeleton's
#: joint is biased 15-70 px during occlusion, which the robust likelihood
#: absorbs. The skin cues share the colour cue's forearm bias and take its value.
#: The learned hand cue is the most precise source on real frames: its palm error
#: is about 5 % of the palm's length (wrist to middle-finger base; 6 px RMSE for a
#: 115 px palm on 256 x 256 crops, 9.9 px for a 210 px palm at 1280 x 720,
#: hand-graph-cnn dev frames 477-582), i.e. 3.5 % per axis (RMSE / sqrt 2), 0.7 px for
#: the reference scene's 18.7 px palm; ``track`` scales every noise with the palm's
#: apparent size and, with ``--adapt-noise``, learns each source's noise and outlier
#: probability per quality band in the recording (:mod:`fusion_pf.filter.calibration`).
DEFAULT_NOISE_PX: Mapping[str, float] = {
    "colour": 12.0,
    "depth": 4.0,
    "skeleton": 20.0,
    "skin_rgb": 12.0,
    "skin_rg": 12.0,
    "skin_lab": 12.0,
    "hand": 0.7,
}

#: Sources whose quality is a probability that the measurement is right (the hand
#: cue's presence score): the robust likelihood's outlier probability for them is
#: ``1 - quality``, floored at :data:`MIN_OUTLIER_PROB` and capped at ``outlier_prob``.
PROBABILITY_QUALITY = frozenset({"hand"})
#: Smallest outlier probability of a :data:`PROBABILITY_QUALITY` source.
MIN_OUTLIER_PROB = 1e-3
#: Quality floor ``q_min`` of the quality widening (at most sqrt(20) ~ 4.5 x the noise).
MIN_QUALITY = 0.05

#: Area of the robust likelihood's uniform outlier density: a 1280 x 800 frame.
DEFAULT_OUTLIER_AREA_PX2 = 1280.0 * 800.0

#: log of the smallest normal float64: below it the paper's linear-space
#: likelihood ``exp(-L / 2 rho)`` underflows to zero.
UNDERFLOW_LOG = math.log(np.finfo(np.float64).tiny)

#: Largest accepted cue coordinate (px): keeps squared distances far from overflow.
MAX_COORD_PX = 1.0e7

#: Likelihood names (``--likelihood`` values).
LIKELIHOODS = ("gaussian", "robust")


def check_noise_px(noise_px: Mapping[str, float]) -> dict[str, float]:
    """Validate a ``{source: sigma_px}`` mapping (finite, > 0) and return a plain dict."""
    if not isinstance(noise_px, Mapping) or not noise_px:
        raise InputError(f"noise_px must be a non-empty mapping source -> sigma px, got {noise_px!r}")
    out = {}
    for source, sigma in noise_px.items():
        try:
            s = float(sigma)
        except (TypeError, ValueError):
            raise InputError(f"noise_px[{source!r}] must be a number > 0 px, got {sigma!r}") from None
        if not (math.isfinite(s) and s > 0.0):
            raise InputError(f"noise_px[{source!r}] must be a finite number > 0 px, got {s}")
        out[str(source)] = s
    return out


def squared_distance(
    positions: np.ndarray,
    z: Sequence[float] | np.ndarray,
    out: np.ndarray | None = None,
    scratch: np.ndarray | None = None,
) -> np.ndarray:
    """Squared Euclidean distance of every particle to a cue (eq. 5).

    Parameters
    ----------
    positions : ndarray, shape (N, 2)
        Particle positions ``(u, v)`` (any memory layout).
    z : (float, float) or ndarray, shape (2,)
        The cue ``(u, v)``.
    out, scratch : ndarray, shape (N,), optional
        Output and work buffers (preallocate them in a loop).

    Returns
    -------
    ndarray, shape (N,)
        ``L = (p_x - phi_x)^2 + (p_y - phi_y)^2``.
    """
    if out is None:
        out = np.empty(positions.shape[0])
    if scratch is None:
        scratch = np.empty_like(out)
    # L = (p_x - phi_x)^2 + (p_y - phi_y)^2
    np.subtract(positions[:, 0], z[0], out=out)
    np.square(out, out=out)
    np.subtract(positions[:, 1], z[1], out=scratch)
    np.square(scratch, out=scratch)
    out += scratch
    return out


def gaussian_loglik(d2: np.ndarray, sigma: float, out: np.ndarray | None = None) -> np.ndarray:
    """Log of the paper's Gaussian likelihood (eq. 6), ``rho = sigma^2``.

    Parameters
    ----------
    d2 : ndarray, shape (N,)
        Squared distances from :func:`squared_distance`.
    sigma : float
        Source noise in px (1-sigma per axis).
    out : ndarray, shape (N,), optional
        Output buffer (may be ``d2`` itself).

    Returns
    -------
    ndarray, shape (N,)
        ``log Lh = -L / (2 rho)`` (unnormalised; step 3 normalises).
    """
    # log Lh = -L / (2 rho), rho = sigma^2
    return np.multiply(d2, -0.5 / (sigma * sigma), out=out)


def effective_sigma(sigma: float, quality: float, q_min: float) -> float:
    """Quality-widened noise ``sigma / sqrt(max(quality, q_min))`` of the robust likelihood."""
    # sigma_eff = sigma / sqrt(max(q, q_min))
    return sigma / math.sqrt(max(quality, q_min))


def quality_sigma(sigma: float, m: Measurement, q_min: float = MIN_QUALITY) -> float:
    """``sigma`` widened by ``m``'s quality (:func:`effective_sigma`), unless ``m``'s source is a
    :data:`PROBABILITY_QUALITY` source, whose quality is its outlier probability instead."""
    return sigma if m.source in PROBABILITY_QUALITY else effective_sigma(sigma, m.quality, q_min)


def robust_loglik(
    d2: np.ndarray,
    sigma: float,
    outlier_prob: float,
    area_px2: float = DEFAULT_OUTLIER_AREA_PX2,
    out: np.ndarray | None = None,
    dims: int = 2,
) -> np.ndarray:
    """Log of the Gaussian + uniform outlier mixture (beyond the paper).

    Parameters
    ----------
    d2 : ndarray, shape (N,)
        Squared distances (eq. 5).
    sigma : float
        Noise of the inlier Gaussian in px (already quality-widened if wanted; mm with ``dims=3``).
    outlier_prob : float
        ``eps`` in (0, 1): prior probability that the cue is an outlier.
    area_px2 : float
        Area ``A`` of the uniform outlier density, px^2 (a volume, mm^3, with ``dims=3``).
    out : ndarray, shape (N,), optional
        Output buffer (may be ``d2`` itself).
    dims : int
        Dimension of the measurement: 2 (pixels) or 3 (world points, mm).

    Returns
    -------
    ndarray, shape (N,)
        ``log((1 - eps) exp(-L / 2 sigma^2) / (2 pi sigma^2)^(dims / 2) + eps / A)``.
    """
    log_in = math.log1p(-outlier_prob) - 0.5 * dims * math.log(2.0 * math.pi * sigma * sigma)
    log_out = math.log(outlier_prob) - math.log(area_px2)
    # a - b = log((1 - eps) / (2 pi sigma^2)^(dims / 2)) - L / (2 sigma^2) - log(eps / A)
    out = np.multiply(d2, -0.5 / (sigma * sigma), out=out)
    out += log_in - log_out
    # log(e^a + e^b) = b + log(1 + e^(a - b))
    np.logaddexp(out, 0.0, out=out)
    out += log_out
    return out


class JointLikelihood:
    """Eqs. 5-7 for a set of per-frame measurements, with preallocated buffers.

    Parameters
    ----------
    noise_px : mapping of str to float
        Per-source noise sigma in px; a measurement from a source not in it is
        an :class:`~fusion_pf.errors.InputError`.
    likelihood : {"gaussian", "robust"}
        The paper's Gaussian (eq. 6) or the Gaussian + uniform mixture.
    outlier_prob : float
        ``eps`` of the robust mixture, in (0, 1).
    use_quality : bool
        Robust only: widen sigma by the cue's quality.
    min_quality : float
        ``q_min`` in (0, 1] of the quality widening.
    outlier_area_px2 : float
        ``A`` of the robust mixture.
    """

    def __init__(
        self,
        noise_px: Mapping[str, float],
        *,
        likelihood: str = "gaussian",
        outlier_prob: float = 0.1,
        use_quality: bool = True,
        min_quality: float = MIN_QUALITY,
        outlier_area_px2: float = DEFAULT_OUTLIER_AREA_PX2,
    ) -> None:
        if likelihood not in LIKELIHOODS:
            raise InputError(f"likelihood must be one of {', '.join(LIKELIHOODS)}, got {likelihood!r}")
        if not (0.0 < float(outlier_prob) < 1.0):
            raise InputError(f"outlier_prob must be in (0, 1), got {outlier_prob}")
        if not (0.0 < float(min_quality) <= 1.0):
            raise InputError(f"min_quality must be in (0, 1], got {min_quality}")
        if not (math.isfinite(float(outlier_area_px2)) and float(outlier_area_px2) > 0.0):
            raise InputError(f"outlier_area_px2 must be a finite number > 0, got {outlier_area_px2}")
        self.noise_px = check_noise_px(noise_px)
        self.likelihood = likelihood
        self.outlier_prob = float(outlier_prob)
        self.source_outlier: dict[str, float] = {}
        self.use_quality = bool(use_quality)
        self.min_quality = float(min_quality)
        self.outlier_area_px2 = float(outlier_area_px2)
        self._scratch: np.ndarray | None = None
        self._work: np.ndarray | None = None

    def check(self, measurements: Sequence[Measurement]) -> list[Measurement]:
        """Validate measurements (known source, finite position within :data:`MAX_COORD_PX`, quality in [0, 1])."""
        out = []
        for m in measurements:
            if not isinstance(m, Measurement):
                raise InputError(f"measurements must be Measurement objects, got {type(m).__name__}")
            if m.source not in self.noise_px:
                raise InputError(
                    f"measurement source {m.source!r} has no noise; known sources: {', '.join(self.noise_px)}"
                )
            if not (abs(m.u) <= MAX_COORD_PX and abs(m.v) <= MAX_COORD_PX):
                raise InputError(
                    f"{m.source} measurement must be finite pixels within +-{MAX_COORD_PX:g}, got ({m.u}, {m.v})"
                )
            if not (0.0 <= m.quality <= 1.0):
                raise InputError(f"{m.source} measurement quality must be in [0, 1], got {m.quality}")
            out.append(m)
        return out

    def sigma(self, m: Measurement) -> float:
        """The noise used for ``m``: its source's sigma, quality-widened when robust (not for a
        :data:`PROBABILITY_QUALITY` source, whose quality is its outlier probability instead)."""
        s = self.noise_px[m.source]
        if self.likelihood == "robust" and self.use_quality:
            return quality_sigma(s, m, self.min_quality)
        return s

    def expected_variance(self, m: Measurement) -> float:
        """``sigma^2 / (1 - eps)``: the measurement's variance over its inlier probability (smaller tells more)."""
        s = self.sigma(m)
        # sigma^2 / P(inlier)
        return s * s / (1.0 - self.outlier(m)) if self.likelihood == "robust" else s * s

    def outlier(self, m: Measurement) -> float:
        """The robust mixture's outlier probability for ``m``: ``1 - quality`` (within
        [:data:`MIN_OUTLIER_PROB`, ``outlier_prob``]) for a :data:`PROBABILITY_QUALITY` source, else
        its source's :meth:`set_outlier` value, else ``outlier_prob``."""
        if m.source in PROBABILITY_QUALITY:
            # eps = 1 - P(the cue is right), bounded
            return min(max(1.0 - m.quality, MIN_OUTLIER_PROB), self.outlier_prob)
        return self.source_outlier.get(m.source, self.outlier_prob)

    def set_outlier(self, source: str, outlier_prob: float) -> None:
        """Use ``outlier_prob`` (in (0, 1)) as ``source``'s outlier probability from now on (not for a
        :data:`PROBABILITY_QUALITY` source, whose quality gives it)."""
        if source not in self.noise_px:
            raise InputError(f"unknown source {source!r}; the likelihood has {', '.join(self.noise_px)}")
        if not (0.0 < float(outlier_prob) < 1.0):
            raise InputError(f"outlier probability of {source} must be in (0, 1), got {outlier_prob!r}")
        self.source_outlier[source] = float(outlier_prob)

    def stacked(self, measurements: Sequence[Measurement]) -> tuple[float, float, float, float]:
        """The Gaussian joint of eq. 7 as one Gaussian: ``(u, v)`` of ``z_bar``, precision ``P`` and ``C``.

        ``sum_phi -L_phi / (2 rho_phi) = -P |p - z_bar|^2 / 2 - C`` with
        ``z_bar = sum_phi z_phi / rho_phi / P``, ``P = sum_phi 1 / rho_phi`` and
        ``C = sum_phi |z_phi - z_bar|^2 / (2 rho_phi)`` (plain floats: a frame has a few sources).
        """
        prec = [1.0 / self.noise_px[m.source] ** 2 for m in measurements]
        total = sum(prec)
        # z_bar = sum_phi z_phi / rho_phi / P
        zu = sum(p * m.u for p, m in zip(prec, measurements)) / total
        zv = sum(p * m.v for p, m in zip(prec, measurements)) / total
        # C = sum_phi |z_phi - z_bar|^2 / (2 rho_phi)
        c = 0.5 * sum(p * ((m.u - zu) ** 2 + (m.v - zv) ** 2) for p, m in zip(prec, measurements))
        return zu, zv, total, c

    def mixture_rows(self, measurements: Sequence[Measurement]) -> np.ndarray:
        """Per source the constants of :func:`robust_loglik` and the loss test, shape (M, 6).

        Columns: ``u, v, -1 / (2 sigma^2), log((1 - eps) / (2 pi sigma^2)) - log(eps / A), log(eps / A)``
        and ``log(2 eps / A)`` (some particle is an inlier when its log-likelihood reaches it).
        """
        rows = []
        for m in measurements:
            sigma, eps = self.sigma(m), self.outlier(m)
            log_in = math.log1p(-eps) - math.log(2.0 * math.pi * sigma * sigma)
            log_out = math.log(eps) - math.log(self.outlier_area_px2)
            thresh = math.log(2.0 * eps / self.outlier_area_px2)
            rows.append((m.u, m.v, -0.5 / (sigma * sigma), log_in - log_out, log_out, thresh))
        return np.array(rows, dtype=np.float64).reshape(-1, 6)

    def source_loglik(self, positions: np.ndarray, m: Measurement, out: np.ndarray) -> np.ndarray:
        """Unnormalised log-likelihood of one source (eqs. 5-6, or the robust mixture)."""
        self._buffers(out)
        d2 = squared_distance(positions, (m.u, m.v), out=out, scratch=self._work)
        if self.likelihood == "robust":
            return robust_loglik(d2, self.sigma(m), self.outlier(m), self.outlier_area_px2, out=d2)
        return gaussian_loglik(d2, self.sigma(m), out=d2)

    def _buffers(self, out: np.ndarray) -> None:
        if self._scratch is None or self._scratch.shape != out.shape:
            self._scratch = np.empty_like(out)
            self._work = np.empty_like(out)

    def __call__(
        self, positions: np.ndarray, measurements: Sequence[Measurement], out: np.ndarray
    ) -> tuple[np.ndarray, bool]:
        """Joint normalised log-likelihood (eqs. 5-7 in log space) and whether the target is lost.

        Gaussian: the product of the per-source Gaussians (eq. 7) is itself a
        Gaussian around the precision-weighted cue mean ``z_bar`` with
        precision ``P = sum_phi 1 / rho_phi``, times a constant; it is computed
        in one pass, ``log Lh = -P |p - z_bar|^2 / 2 - C``. Normalising each
        source by its maximum (step 3) shifts every particle's log-likelihood
        by the same constant, which eq. 2 removes; here the joint is normalised
        by its own maximum instead (same weights). Robust: the per-source
        mixtures are summed, each normalised by its maximum.

        Parameters
        ----------
        positions : ndarray, shape (N, 2)
            Particle positions.
        measurements : sequence of Measurement
            Validated measurements of this frame (at least one).
        out : ndarray, shape (N,)
            Output buffer.

        Returns
        -------
        joint : ndarray, shape (N,)
            Normalised joint log-likelihood, <= 0 with maximum 0.
        lost : bool
            Gaussian: the unnormalised joint likelihood of every particle
            underflows float64 (``max log Lh <`` :data:`UNDERFLOW_LOG`), where
            the paper's linear-space filter would divide 0 by 0. Robust: every
            cue is more likely an outlier than an inlier for every particle
            (the whole cloud is far from all cues). Either way the particles
            no longer cover the target.
        """
        self._buffers(out)
        if self.likelihood == "gaussian":
            zu, zv, total, c = self.stacked(measurements)
            d2 = squared_distance(positions, (zu, zv), out=out, scratch=self._work)
            # log Lh = sum_phi -L_phi / (2 rho_phi) = -P |p - z_bar|^2 / 2 - C   (eqs. 5-7)
            joint = np.multiply(d2, -0.5 * total, out=d2)
            peak = float(joint.max())
            # Lh~ = Lh / max Lh   (step 3)
            joint -= peak
            return joint, peak - c < UNDERFLOW_LOG
        out.fill(0.0)
        peaks = 0.0
        inlier = False
        assert self._scratch is not None, "allocated by _buffers"
        for m in measurements:
            ll = self.source_loglik(positions, m, self._scratch)
            peak = float(ll.max())
            # some particle has (1 - eps) N(d) >= eps / A  <=>  log Lh >= log(2 eps / A)
            inlier = inlier or peak >= math.log(2.0 * self.outlier(m) / self.outlier_area_px2)
            peaks += peak
            # Lh = Lh_K (x) Lh_C (x) Lh_D  ->  log Lh = sum_phi log Lh_phi
            out += ll
        # Lh~_phi = Lh_phi / max Lh_phi  (step 3, all sources at once)
        out -= peaks
        return out, not inlier
