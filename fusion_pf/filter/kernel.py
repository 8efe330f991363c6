"""Compiled phases of :meth:`~fusion_pf.filter.pf.ParticleFilter.step` (numba).

At the default N = 100 a step of separate numpy calls is mostly interpreter
overhead (~20 array operations of a microsecond or two each); at large N it is
memory traffic (every operation streams the arrays once more). These kernels
fuse the phases into a few compiled passes over the ``(4, N)`` particle rows:

* :func:`kernels` ``.predict`` -- eq. 4 given the normals; ``.predict_drawn``
  draws them first from the filter's :class:`numpy.random.Generator` inside the
  kernel (numba's port of numpy's ziggurat on the same bit generator: the same
  numbers, in the same order, as ``rng.standard_normal(out=rows)``, at about
  half numpy's cost per normal, but ~5 us more per call to pass the Generator:
  used from :data:`DRAW_IN_KERNEL_N` particles on);
* ``.gaussian`` -- eqs. 5-7 for the stacked Gaussian sources in one pass, with
  the loss test;
* ``.robust`` -- the same with the per-source Gaussian + uniform mixtures;
* ``.weigh`` -- eq. 3 and eq. 2 (log-weights, normalised weights), the point
  estimate, the weighted covariance and the ESS;
* ``.systematic`` -- systematic resampling for one uniform offset, copying the
  drawn particles into the spare particle array in the same pass.

The maths is that of the numpy functions they replace
(:mod:`~fusion_pf.filter.motion`, :mod:`~fusion_pf.filter.likelihood`,
:mod:`~fusion_pf.filter.estimate`, :mod:`~fusion_pf.filter.resample`), element
by element; only the order of floating-point sums differs (sequential here),
and ties of the robust mean's top set are broken by index.

Compiled on first use and cached on disk (``cache=True``, numba's cache
directory: ``__pycache__`` next to this file, or the user cache when that is not
writable). :func:`warm_up` loads them in a background thread so that no frame
of a run waits for numba.
"""

from __future__ import annotations

import functools
import threading
from types import SimpleNamespace

import numpy as np

__all__ = ["DRAW_IN_KERNEL_N", "ESTIMATOR_CODES", "kernels", "warm_up"]

#: Estimator name -> code of ``kernels().weigh``.
ESTIMATOR_CODES = {"weighted_mean": 0, "robust_mean": 1, "map": 2}

#: From this many particles eq. 4's normals are drawn inside the kernel (``predict_drawn``;
#: interleaved with Stone Soup, N = 100: 22 us a step with numpy's draws, 37 us in the kernel).
DRAW_IN_KERNEL_N = 1000


_lock = threading.Lock()
_ready: SimpleNamespace | None = None


def kernels() -> SimpleNamespace:
    """The compiled kernels (compiled or loaded from numba's cache on first call; thread-safe)."""
    global _ready
    # a step calls this 3-4 times: once built, no lock (~0.4 us a call)
    if _ready is None:
        with _lock:
            _ready = _build()
    return _ready


@functools.cache
def _build() -> SimpleNamespace:
    import numba

    jit = numba.njit(cache=True, nogil=True, boundscheck=False, error_model="numpy")

    @jit
    def predict(x, noise, std, dt, lo, hi):  # pragma: no cover - runs compiled
        # x_k = M x_(k-1) + gamma (x) sigma_x   (eq. 4); noise rows lo..hi-1 hold the normals
        n = x.shape[1]
        for i in range(n):
            x[0, i] += dt * x[2, i]
            x[1, i] += dt * x[3, i]
        for r in range(lo, hi):
            s = std[r]
            for i in range(n):
                x[r, i] += noise[r, i] * s

    @jit
    def predict_drawn(x, rng, noise, std, dt, lo, hi):  # pragma: no cover - runs compiled
        # predict, its normals drawn here row by row: numpy's rng.standard_normal(out=noise[lo:hi])
        for r in range(lo, hi):
            for i in range(x.shape[1]):
                noise[r, i] = rng.standard_normal()
        predict(x, noise, std, dt, lo, hi)

    @jit
    def gaussian(x, zu, zv, half_prec, joint):  # pragma: no cover - runs compiled
        # log Lh = -P |p - z_bar|^2 / 2 (eqs. 5-7 stacked); returns its maximum
        n = x.shape[1]
        peak = -np.inf
        for i in range(n):
            du = x[0, i] - zu
            dv = x[1, i] - zv
            ll = (du * du + dv * dv) * half_prec
            joint[i] = ll
            if ll > peak:
                peak = ll
        # Lh~ = Lh / max Lh   (step 3)
        for i in range(n):
            joint[i] -= peak
        return peak

    @jit
    def robust(x, src, joint):  # pragma: no cover - runs compiled
        # src rows: u, v, -1 / (2 sigma^2), log_in - log_out, log_out, inlier threshold
        n = x.shape[1]
        for i in range(n):
            joint[i] = 0.0
        peaks = 0.0
        inlier = False
        for s in range(src.shape[0]):
            zu, zv, a, gap, log_out, thresh = src[s, 0], src[s, 1], src[s, 2], src[s, 3], src[s, 4], src[s, 5]
            peak = -np.inf
            for i in range(n):
                du = x[0, i] - zu
                dv = x[1, i] - zv
                t = (du * du + dv * dv) * a + gap
                # log(e^t + 1) as numpy's logaddexp(t, 0), then + log(eps / A)
                ll = (t + np.log1p(np.exp(-t)) if t > 0.0 else np.log1p(np.exp(t))) + log_out
                joint[i] += ll
                if ll > peak:
                    peak = ll
            inlier = inlier or peak >= thresh
            peaks += peak
        # Lh~_phi = Lh_phi / max Lh_phi   (step 3, all sources at once)
        for i in range(n):
            joint[i] -= peaks
        return inlier

    @jit
    def weigh(logw, joint, mode, w, x, centres, estimator, top_k):  # pragma: no cover - runs compiled
        # mode 0: weights as they are; 1: add joint, then normalise; 2: normalise
        n = logw.shape[0]
        if mode > 0:
            peak = -np.inf
            for i in range(n):
                # w_k ∝ w_(k-1) p(z_k | x_k)   (eq. 3, logs)
                if mode == 1:
                    logw[i] += joint[i]
                if logw[i] > peak:
                    peak = logw[i]
            total = 0.0
            for i in range(n):
                e = np.exp(logw[i] - peak)
                w[i] = e
                total += e
            # w~_i = w_i / sum_j w_j   (eq. 2)
            scale = 1.0 / total
            shift = peak + np.log(total)
            for i in range(n):
                w[i] *= scale
                logw[i] -= shift
        mu = 0.0
        mv = 0.0
        sw2 = 0.0
        wsum = 0.0
        for i in range(n):
            wi = w[i]
            mu += wi * x[0, i]
            mv += wi * x[1, i]
            sw2 += wi * wi
            wsum += wi
        mu /= wsum
        mv /= wsum
        # C = sum_i w_i (p_i - m)(p_i - m)^T
        cuu = 0.0
        cuv = 0.0
        cvv = 0.0
        for i in range(n):
            du = x[0, i] - mu
            dv = x[1, i] - mv
            cuu += w[i] * du * du
            cuv += w[i] * du * dv
            cvv += w[i] * dv * dv
        if estimator == 2:
            # x_hat = p_argmax(w)
            best = np.argmax(w)
            eu, ev = centres[0, best], centres[1, best]
        else:
            k = n if estimator == 0 else top_k
            thr = -1.0 if k >= n else np.partition(w, n - k)[n - k]
            above = 0
            if k < n:
                for i in range(n):
                    above += w[i] > thr
            ties = k - above
            # x_hat = sum_top w_i p_i / sum_top w_i  (top: the k largest weights, ties by index)
            eu = 0.0
            ev = 0.0
            ws = 0.0
            for i in range(n):
                wi = w[i]
                if wi > thr or (wi == thr and ties > 0):
                    if wi == thr:
                        ties -= 1
                    eu += wi * centres[0, i]
                    ev += wi * centres[1, i]
                    ws += wi
            eu /= ws
            ev /= ws
        # ESS = 1 / sum_i w_i^2
        return eu, ev, cuu, cuv, cvv, 1.0 / sw2

    @jit
    def systematic(w, offset, x, out, cdf):  # pragma: no cover - runs compiled
        # out[:, k] = x[:, i_k] for the systematic draws i_k (the copy fused into the resampling pass)
        # #{j : (j + U) / N < c_i} = ceil(N c_i - U), clipped to [0, N]; c scaled to end at exactly N
        n = w.shape[0]
        c = 0.0
        for i in range(n):
            c += w[i]
            cdf[i] = c
        total = cdf[n - 1]
        # the last particle of positive weight: the first i with c_i = total (c ascends: search back)
        last = n - 1
        while last > 0 and cdf[last - 1] >= total:
            last -= 1
        scale = n / total
        below_prev = 0
        k = 0
        rows = x.shape[0]
        for i in range(n):
            nc = n if i >= last else cdf[i] * scale
            b = int(min(max(np.ceil(nc - offset), 0.0), n))
            for _ in range(b - below_prev):
                for r in range(rows):
                    out[r, k] = x[r, i]
                k += 1
            below_prev = b

    return SimpleNamespace(
        predict=predict,
        predict_drawn=predict_drawn,
        gaussian=gaussian,
        robust=robust,
        weigh=weigh,
        systematic=systematic,
    )


_warm: threading.Thread | None = None


def warm_up(wait: bool = False) -> None:
    """Load (or compile) every kernel in a daemon thread, started once; ``wait``: until they are ready.

    Started early (``fusion-pf track`` starts it before it opens the recording) the
    load overlaps the run's start-up; :func:`~fusion_pf.pipeline.track` then waits
    for it before its first frame, so no frame pays numba's start-up (~0.5 s of
    CPU: importing numba and its typing registry, then each cached kernel).
    """
    global _warm
    with _lock:
        if _warm is None:
            _warm = threading.Thread(target=_compile_all, name="fusion-pf-kernels", daemon=True)
            _warm.start()
    if wait:
        _warm.join()


def _compile_all() -> None:
    from .resample import residual_trusted

    residual_trusted(np.array([0.25, 0.75]), np.random.default_rng(0))
    k = _build()
    x = np.zeros((4, 2))
    joint, w, logw = np.zeros(2), np.zeros(2), np.zeros(2)
    k.predict(x, np.zeros((4, 2)), np.ones(4), 1.0, 0, 4)
    for bit_generator in (np.random.PCG64, np.random.SFC64):
        k.predict_drawn(x, np.random.Generator(bit_generator(0)), np.zeros((4, 2)), np.ones(4), 1.0, 0, 4)
    k.gaussian(x, 0.0, 0.0, -0.5, joint)
    k.robust(x, np.zeros((1, 6)), joint)
    k.weigh(logw, joint, 1, w, x, x[:2], 0, 1)
    k.systematic(w + 0.5, 0.5, x, np.zeros((4, 2)), joint)
