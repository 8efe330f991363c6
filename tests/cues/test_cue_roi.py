import math

import numpy as np
import pytest

from fusion_pf.cues.roi import PAPER_HALF_SIZE, make_roi
from fusion_pf.errors import InputError


def test_default_window_is_the_papers_141():
    r = make_roi(320, 200, (640, 400))
    assert r.shape == (141, 141) and r.offset == (320 - PAPER_HALF_SIZE, 200 - PAPER_HALF_SIZE)


def test_depth_scaled_window_covers_fixed_physical_size():
    near = make_roi(320, 200, (640, 400), depth_mm=1000, fx=500, extent_mm=100)
    far = make_roi(320, 200, (640, 400), depth_mm=2000, fx=500, extent_mm=100)
    assert near.shape == (101, 101) and far.shape == (51, 51)
    assert near.palm_area == pytest.approx(math.pi * (55 * 0.5) ** 2)
    assert far.palm_area == pytest.approx(near.palm_area / 4)


def test_window_is_clipped_at_the_frame_edge():
    r = make_roi(3, 395, (640, 400), half_size=20)
    assert (r.x0, r.y0, r.x1, r.y1) == (0, 375, 24, 400)
    img = np.zeros((400, 640))
    assert r.crop(img).shape == r.shape


@pytest.mark.parametrize("u,v", [(-50, 10), (700, 10), (10, 400), (math.nan, 5), (5, math.inf)])
def test_prior_outside_or_not_finite_gives_empty_window(u, v):
    assert make_roi(u, v, (640, 400)).empty


@pytest.mark.parametrize(
    "kwargs,needle",
    [({"half_size": 0}, "half_size"), ({"extent_mm": 1}, "extent_mm"), ({"min_half": -1}, "min_half")],
)
def test_bad_options_raise_one_line_input_error(kwargs, needle):
    with pytest.raises(InputError, match=needle) as e:
        make_roi(10, 10, (64, 40), **kwargs)
    assert "\n" not in str(e.value)
