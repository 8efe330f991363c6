"""Compiled phases of :meth:`~fusion_pf.filter.pf.ParticleFilter.step` (numba).

At N = 100-300 (300 is the default) a step of separate numpy calls is mostly interpreter
overhead (~20 array operations of a microsecond or two each); at large N it is
memory traffic (every operation streams the arrays once more). These kernels
fuse the phases into a few compiled passes over the ``(4, N)`` particle rows:

* :func:`kernels` ``.normals`` -- float32 N(0, 1) from the filter's own SFC64
  stream (:func:`stream`): numpy's float32 ziggurat (256 layers, one 32-bit draw per
  candidate, every rejection branch) on numpy's SFC64, inlined, the two halves of a
  64-bit word tested at once on the fast path: exactly
  ``Generator(SFC64).standard_normal(k, dtype=np.float32)`` from the same state, at
  ~1.5 ns a normal (numba's port of the float64 ziggurat through the Generator's
  function pointers: ~2.6 ns; numpy's own: ~7 ns). float32 normals are exact
  normals at 2^-23 resolution, far below eq. 4's px-scale noise;
* ``.move`` -- eq. 4 with those normals, then eqs. 5-7 for the stacked Gaussian
  sources (unnormalised; their maximum decides the loss test): one call for the
  whole prediction and likelihood;
* ``.gaussian`` -- eqs. 5-7 for the stacked Gaussian sources in one pass, with
  the loss test (a step that did not predict first);
* ``.robust`` -- the same with the per-source Gaussian + uniform mixtures;
* ``.shift`` -- eq. 3 in logs and ``log w - max log w``, whose ``exp`` the caller
  takes with numpy (its SIMD exp: ~0.6 ns an element against ~2.9 ns for the
  libm call a compiled loop makes);
* ``.weigh`` -- eq. 2 (normalised weights and log-weights), the point estimate,
  the weighted covariance and the ESS;
* ``.systematic`` -- systematic resampling for one uniform offset: the drawn
  indices, then the particles gathered row by row into the spare array.

The maths is that of the numpy functions they replace
(:mod:`~fusion_pf.filter.motion`, :mod:`~fusion_pf.filter.likelihood`,
:mod:`~fusion_pf.filter.estimate`, :mod:`~fusion_pf.filter.resample`), element
by element; only the order of floating-point sums differs (``shift`` and
``weigh`` let LLVM reassociate them into SIMD lanes), and ties of the robust
mean's top set are broken by index. Every kernel runs on the calling thread
(no numba threads: a step is single-core work).

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

__all__ = ["ESTIMATOR_CODES", "kernels", "stream", "warm_up"]

#: Estimator name -> code of ``kernels().weigh``.
ESTIMATOR_CODES = {"weighted_mean": 0, "robust_mean": 1, "map": 2}


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
    from numba.np.random._constants import fi_float, ki_float, wi_float, ziggurat_nor_inv_r_f, ziggurat_nor_r_f

    jit = numba.njit(cache=True, nogil=True, boundscheck=False, error_model="numpy")
    # reassociation lets LLVM vectorise the sums and maxima (only their rounding order changes)
    fast = numba.njit(
        cache=True, nogil=True, boundscheck=False, error_model="numpy", fastmath={"reassoc", "nsz", "contract", "nnan"}
    )

    u1, u3, u11, u24, u32, u40 = (numba.uint64(k) for k in (1, 3, 11, 24, 32, 40))
    low32 = numba.uint64(0xFFFFFFFF)
    nine, mant, layer, sign = (numba.uint32(k) for k in (9, 0x7FFFFF, 0xFF, 0x100))
    f32 = numba.float32

    @jit
    def sfc64(a, b, c, w):  # pragma: no cover - runs compiled
        # numpy's SFC64 step on the state (a, b, c, counter w): the word, then the next state
        out = a + b + w
        return out, b ^ (b >> u11), c + (c << u3), ((c << u24) | (c >> u40)) + out, w + u1

    @jit
    def next32(s):  # pragma: no cover - runs compiled
        # numpy's next_uint32 of SFC64: a word's low half, its high half kept for the next call
        a, b, c, w, has, buf = s
        if has:
            return numba.uint32(buf), (a, b, c, w, numba.uint64(0), buf)
        out, a, b, c, w = sfc64(a, b, c, w)
        return numba.uint32(out & low32), (a, b, c, w, u1, out >> u32)

    @jit
    def next_float(s):  # pragma: no cover - runs compiled
        r, s = next32(s)
        return f32(f32(r >> numba.uint32(8)) * f32(1.0) / f32(16777216.0)), s

    @jit
    def normal(s):  # pragma: no cover - runs compiled
        # numpy's random_standard_normal_f (256-layer ziggurat on 32-bit draws), every branch
        while True:
            r, s = next32(s)
            idx = r & layer
            rabs = (r >> nine) & mant
            x = f32(f32(rabs) * wi_float[idx])
            if r & sign:
                x = -x
            if rabs < ki_float[idx]:
                return x, s
            if idx == 0:
                # the tail beyond r: Marsaglia's exponential method
                while True:
                    f1, s = next_float(s)
                    f2, s = next_float(s)
                    xx = f32(-ziggurat_nor_inv_r_f * np.log1p(f32(-f1)))
                    yy = f32(-np.log1p(f32(-f2)))
                    if f32(yy + yy) > f32(xx * xx):
                        tail = f32(ziggurat_nor_r_f + xx)
                        return (-tail if (rabs >> numba.uint32(8)) & numba.uint32(1) else tail), s
            f, s = next_float(s)
            if (fi_float[idx - 1] - fi_float[idx]) * f + fi_float[idx] < f32(np.exp(-f32(0.5) * x * x)):
                return x, s

    @jit
    def normals(state, out):  # pragma: no cover - runs compiled
        # out[:] = N(0, 1) float32, exactly numpy's Generator(SFC64).standard_normal(out.size, dtype=float32)
        # continuing from state (a, b, c, counter, has_uint32, uinteger), which is advanced
        a, b, c, w, has, buf = state[0], state[1], state[2], state[3], state[4], state[5]
        n = out.shape[0]
        i = 0
        while i < n:
            # one word, two normals while both halves take the ziggurat's fast path (98.6 % of words)
            while has == 0 and i + 1 < n:
                r = a + b + w
                lo, hi = numba.uint32(r & low32), numba.uint32(r >> u32)
                ra, rb = (lo >> nine) & mant, (hi >> nine) & mant
                ia, ib = lo & layer, hi & layer
                if ra >= ki_float[ia] or rb >= ki_float[ib]:
                    break
                _, a, b, c, w = sfc64(a, b, c, w)
                xa, xb = f32(f32(ra) * wi_float[ia]), f32(f32(rb) * wi_float[ib])
                out[i] = -xa if lo & sign else xa
                out[i + 1] = -xb if hi & sign else xb
                i += 2
            if i < n:
                # the rest of the ziggurat from that word (or a left-over half, or the last normal)
                out[i], (a, b, c, w, has, buf) = normal((a, b, c, w, has, buf))
                i += 1
        state[0], state[1], state[2], state[3], state[4], state[5] = a, b, c, w, has, buf

    @jit
    def stacked(x, zu, zv, half_prec, joint):  # pragma: no cover - runs compiled
        # log Lh = -P |p - z_bar|^2 / 2 (eqs. 5-7 stacked) into joint; returns its maximum
        peak = -np.inf
        for i in range(x.shape[1]):
            du = x[0, i] - zu
            dv = x[1, i] - zv
            ll = (du * du + dv * dv) * half_prec
            joint[i] = ll
            peak = max(peak, ll)
        return peak

    @jit
    def move(x, state, noise, std, dt, lo, hi, zu, zv, half_prec, joint):  # pragma: no cover - runs compiled
        # x_k = M x_(k-1) + gamma (x) sigma_x   (eq. 4), the normals of rows lo..hi-1 drawn into noise first;
        # then log Lh = -P |p - z_bar|^2 / 2 (eqs. 5-7 stacked, unnormalised) into joint; returns its maximum
        n = x.shape[1]
        normals(state, noise[lo:hi].reshape(-1))
        for i in range(n):
            x[0, i] += dt * x[2, i]
            x[1, i] += dt * x[3, i]
        for r in range(lo, hi):
            s = std[r]
            for i in range(n):
                x[r, i] += noise[r, i] * s
        return stacked(x, zu, zv, half_prec, joint)

    @jit
    def gaussian(x, zu, zv, half_prec, joint):  # pragma: no cover - runs compiled
        # log Lh = -P |p - z_bar|^2 / 2 (eqs. 5-7 stacked); returns its maximum
        n = x.shape[1]
        peak = stacked(x, zu, zv, half_prec, joint)
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

    @fast
    def shift(logw, joint, add, w):  # pragma: no cover - runs compiled
        # log w_k = log w_(k-1) + log p(z_k | x_k)   (eq. 3, logs; when add), then w = log w - max log w
        n = logw.shape[0]
        if add:
            for i in range(n):
                logw[i] += joint[i]
        peak = -np.inf
        for i in range(n):
            peak = max(peak, logw[i])
        for i in range(n):
            w[i] = logw[i] - peak
        return peak

    @fast
    def weigh(logw, w, peak, normalise, x, centres, estimator, top_k):  # pragma: no cover - runs compiled
        # normalise: w holds exp(log w - peak); w~_i = w_i / sum_j w_j   (eq. 2), log w likewise
        n = logw.shape[0]
        if normalise:
            total = 0.0
            for i in range(n):
                total += w[i]
            scale = 1.0 / total
            drop = peak + np.log(total)
            for i in range(n):
                w[i] *= scale
                logw[i] -= drop
        mu = 0.0
        mv = 0.0
        eu = 0.0
        ev = 0.0
        sw2 = 0.0
        wsum = 0.0
        for i in range(n):
            wi = w[i]
            mu += wi * x[0, i]
            mv += wi * x[1, i]
            eu += wi * centres[0, i]
            ev += wi * centres[1, i]
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
        if estimator == 0:
            # x_hat = sum_i w_i p_i / sum_i w_i
            eu /= wsum
            ev /= wsum
        elif estimator == 2:
            # x_hat = p_argmax(w)
            best = np.argmax(w)
            eu, ev = centres[0, best], centres[1, best]
        else:
            k = top_k
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
    def systematic(w, offset, x, out, cdf, idx):  # pragma: no cover - runs compiled
        # out[:, k] = x[:, i_k] for the systematic draws i_k (idx: the i_k)
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
        k = 0
        for i in range(n):
            y = (n if i >= last else cdf[i] * scale) - offset
            # ceil(y) clipped to [0, N]: the draws below c_i are particle i's up to there
            t = int(y)
            b = min(max(t + (y > t), 0), n)
            while k < b:
                idx[k] = i
                k += 1
        for r in range(x.shape[0]):
            for j in range(n):
                out[r, j] = x[r, idx[j]]

    return SimpleNamespace(
        normals=normals,
        move=move,
        shift=shift,
        gaussian=gaussian,
        robust=robust,
        weigh=weigh,
        systematic=systematic,
    )


def stream(rng: np.random.Generator) -> np.ndarray:
    """A new SFC64 stream for :func:`kernels` ``.normals`` / ``.move``, seeded from ``rng``.

    Returns the state ``(a, b, c, counter, has_uint32, uinteger)`` as 6 uint64: that of
    ``numpy.random.SFC64(seed)`` for 128 bits ``seed`` drawn from ``rng`` (numpy's
    SeedSequence spreads them), so the kernels' normals are exactly
    ``Generator(SFC64(seed)).standard_normal(k, dtype=np.float32)``.
    """
    st = np.random.SFC64(rng.integers(0, 2**63, size=2, dtype=np.uint64)).state
    return np.array([*st["state"]["state"], st["has_uint32"], st["uinteger"]], dtype=np.uint64)


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
    k.move(
        x, stream(np.random.default_rng(0)), np.zeros((4, 2), np.float32), np.ones(4), 1.0, 0, 4, 0.0, 0.0, -0.5, joint
    )
    k.gaussian(x, 0.0, 0.0, -0.5, joint)
    k.robust(x, np.zeros((1, 6)), joint)
    peak = k.shift(logw, joint, True, w)
    np.exp(w, out=w)
    k.weigh(logw, w, peak, True, x, x[:2], 0, 1)
    k.systematic(w, 0.5, x, np.zeros((4, 2)), joint, np.zeros(2, np.int64))
