"""Property tests: on arbitrary small inputs every cue returns None or a finite measurement."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fusion_pf.cues import ColourCue, DepthCue, RgbRuleSkin, RgChromaSkin, SkinCue, make_roi

shapes = st.tuples(st.integers(1, 16), st.integers(1, 16))


def _ok(res, roi_shape=None):
    m = res.measurement
    if m is not None:
        assert math.isfinite(m.u) and math.isfinite(m.v) and 0.0 <= m.quality <= 1.0
    for img in res.stages.values():
        assert img.shape[:2] == roi_shape
    assert res.latency_ns >= 0


@settings(max_examples=60, deadline=None)
@given(data=st.data(), shape=shapes)
def test_any_small_colour_input(data, shape):
    h, w = shape
    a = data.draw(arrays(np.uint8, (h, w, 3)))
    b = data.draw(arrays(np.uint8, (h, w, 3)))
    u = data.draw(st.one_of(st.floats(-20, 40), st.just(math.nan)))
    v = data.draw(st.one_of(st.floats(-20, 40), st.just(math.nan)))
    roi = make_roi(u, v, (w, h), half_size=data.draw(st.integers(1, 10)))
    shape2 = roi.shape if not roi.empty else None
    for r in (roi, None):
        expect = (h, w) if r is None else shape2
        res = ColourCue(min_area=data.draw(st.integers(0, 5)), dilate=1)(a, b, roi=r, stages=True)
        _ok(res, expect)
        for model in (RgChromaSkin(), RgbRuleSkin()):
            _ok(SkinCue(model, min_area=0)(a, roi=r, stages=True), expect)


@settings(max_examples=60, deadline=None)
@given(data=st.data(), shape=shapes)
def test_any_small_depth_input(data, shape):
    h, w = shape
    d = data.draw(arrays(np.uint16, (h, w), elements=st.sampled_from([0, 1, 500, 1200, 1250, 3000, 65535])))
    b = data.draw(arrays(np.uint16, (h, w), elements=st.sampled_from([0, 1, 1500, 3000, 65535])))
    cue = DepthCue(min_area=0, nearest_mm=data.draw(st.sampled_from([None, 1, 50])))
    for _ in range(2):
        _ok(cue(d, b, stages=True), (h, w))
