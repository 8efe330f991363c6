import math

import numpy as np
import pytest

from fusion_pf.cues.regions import (
    Region,
    clear_border,
    dilate,
    fill_holes,
    largest_region,
    measure,
    region_detections,
    region_quality,
    remove_small,
    two_means,
)


def _mask(h=40, w=40):
    return np.zeros((h, w), np.uint8)


def test_remove_small_keeps_only_big_regions():
    m = _mask()
    m[2:4, 2:4] = 255  # 4 px
    m[10:20, 10:20] = 255  # 100 px
    out = remove_small(m, 5)
    assert out[2:4, 2:4].max() == 0
    assert (out[10:20, 10:20] == 255).all()
    assert out.dtype == np.uint8 and out.shape == m.shape


def test_fill_holes_fills_enclosed_but_not_border_open_zeros():
    m = _mask()
    m[5:25, 5:25] = 255
    m[10:15, 10:15] = 0  # enclosed hole
    m[0:3, 30:40] = 0
    m[0:10, 28] = 255  # a wall that touches the border: its side is not a hole
    out = fill_holes(m)
    assert (out[10:15, 10:15] == 255).all()
    assert out[0:3, 30:40].max() == 0
    assert np.array_equal(out & ~np.uint8(0), out)  # still binary values
    assert set(np.unique(out)) <= {0, 255}


def test_dilate_grows_by_radius():
    m = _mask()
    m[20, 20] = 255
    out = dilate(m, 3)
    assert out[20, 23] == 255 and out[20, 24] == 0
    assert np.array_equal(dilate(m, 0), m)


def test_clear_border_removes_touching_regions_only():
    m = _mask()
    m[0:5, 0:5] = 255
    m[15:20, 15:20] = 255
    m[35:40, 10:12] = 255
    out = clear_border(m)
    assert out[0:5, 0:5].max() == 0 and out[35:40, 10:12].max() == 0
    assert (out[15:20, 15:20] == 255).all()


def test_largest_region_centroid_and_area():
    m = _mask(50, 60)
    m[10:21, 30:41] = 255  # 121 px square centred at (35, 15)
    m[40:43, 2:5] = 255
    r = largest_region(m)
    assert r is not None
    assert r.area == 121 and r.bbox == (30, 10, 11, 11)
    assert (r.u, r.v) == pytest.approx((35.0, 15.0))


@pytest.mark.parametrize("shape", [(0, 0), (1, 1), (8, 8)])
def test_largest_region_degenerate_is_none(shape):
    assert largest_region(np.zeros(shape, np.uint8)) is None
    for f in (fill_holes, clear_border):
        assert f(np.zeros(shape, np.uint8)).shape == shape
    assert remove_small(np.zeros(shape, np.uint8), 10).shape == shape


def test_largest_region_respects_min_area():
    m = _mask()
    m[5:8, 5:8] = 255
    assert largest_region(m, min_area=10) is None
    assert largest_region(m, min_area=9) is not None


def test_region_quality_peaks_for_a_disc_of_the_expected_area():
    vv, uu = np.mgrid[0:80, 0:80]
    disc = np.where((uu - 40) ** 2 + (vv - 40) ** 2 <= 15**2, np.uint8(255), np.uint8(0))
    r = largest_region(disc)
    q_match = region_quality(r, palm_area=math.pi * 15**2)
    q_big = region_quality(r, palm_area=4 * math.pi * 15**2)
    line = Region(10.0, 10.0, 60, (0, 10, 60, 1))
    q_line = region_quality(line, palm_area=60)
    assert q_match > 0.9
    assert q_big == pytest.approx(q_match / 4, rel=0.05)
    assert 0.0 <= q_line < q_match
    assert 0.0 <= q_line <= 1.0


def test_measure_adds_offset_and_extras():
    m = _mask()
    m[10:15, 20:25] = 255
    meas = measure(m, (100, 50), "colour", palm_area=25)
    assert (meas.u, meas.v) == pytest.approx((122.0, 62.0))
    assert meas.extras["area"] == 25 and meas.extras["bbox"] == [120, 60, 5, 5]
    assert measure(_mask(), (0, 0), "colour", palm_area=25) is None


@pytest.mark.parametrize("seed", range(12))
def test_region_filters_equal_scipy_labelling(seed):
    # an independent labelling (scipy.ndimage, 8-connectivity) as the reference for every region filter
    from scipy import ndimage

    from fusion_pf.cues.regions import keep_marked

    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 90, size=2)
    m = np.where(rng.random((h, w)) < rng.uniform(0.05, 0.6), np.uint8(255), np.uint8(0))
    labels, n = ndimage.label(m > 0, structure=np.ones((3, 3)))
    areas = np.bincount(labels.ravel(), minlength=n + 1)
    min_area = int(rng.integers(2, 30))
    expected = (areas >= min_area)[labels] & (labels > 0)
    np.testing.assert_array_equal(remove_small(m, min_area) == 255, expected)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    np.testing.assert_array_equal(clear_border(m) == 255, (labels > 0) & ~np.isin(labels, border))
    marker = rng.random((h, w)) < 0.01
    marked = np.unique(labels[marker & (labels > 0)])
    np.testing.assert_array_equal(
        keep_marked(m, marker.astype(np.uint8)) == 255, np.isin(labels, marked) & (labels > 0)
    )


def test_a_region_holding_two_joined_targets_is_split_between_them():
    import cv2

    from fusion_pf.cues.regions import region_detections, split_region

    m = _mask(60, 120)
    cv2.circle(m, (40, 30), 15, 255, -1)  # two palms side by side, touching: one region
    cv2.circle(m, (66, 30), 15, 255, -1)
    whole = region_detections(m, (100, 200), "colour", palm_area=700.0)
    assert len(whole) == 1 and abs(whole[0].u - 153.0) < 0.5  # the pair's middle
    parts = region_detections(m, (100, 200), "colour", palm_area=700.0, parts=((145.0, 228.0), (162.0, 232.0)))
    assert [d.measurement.extras["part"] for d in parts] == [0, 1]
    assert abs(parts[0].u - 140.0) < 3.0 and abs(parts[1].u - 166.0) < 3.0  # each palm's centre
    assert all(abs(d.v - 230.0) < 1.0 for d in parts)
    # points outside the region's box: not split
    far = region_detections(m, (100, 200), "colour", palm_area=700.0, parts=((145.0, 228.0), (300.0, 232.0)))
    assert len(far) == 1 and "part" not in far[0].measurement.extras
    # a mask whose pixels all lie nearer one seed cannot be split
    assert split_region(m[:, :60] > 0, np.array([[40.0, 30.0], [110.0, 30.0]])) is None


def _palm_and_forearm(h=200, w=240):
    """A palm disc (radius 25, centre (80, 100)) with a forearm bar (16 px wide) running 110 px to its right."""
    m = np.zeros((h, w), np.uint8)
    yy, xx = np.mgrid[:h, :w]
    m[(xx - 80) ** 2 + (yy - 100) ** 2 <= 25**2] = 255
    m[92:109, 80:215] = 255
    return m


def test_core_centre_is_the_palm_centre_whatever_forearm_is_attached():
    m = _palm_and_forearm()
    plain = largest_region(m)
    core = largest_region(m, core=True)
    assert plain is not None and core is not None
    assert plain.u - 80 > 20  # the centroid is pulled along the forearm
    assert (core.u, core.v) == pytest.approx((80.0, 100.0), abs=0.5)
    assert (core.area, core.bbox) == (plain.area, plain.bbox)
    assert plain.radius is None and core.radius == pytest.approx(25.0, abs=1.0)  # the palm's, not the forearm's 8.5
    shifted = np.roll(m, (7, -11), axis=(0, 1))
    moved = measure(shifted, (3, 5), "colour", palm_area=2000.0, core=True)
    assert (moved.u, moved.v) == pytest.approx((80.0 - 11 + 3, 100.0 + 7 + 5), abs=0.5)
    assert (
        moved.extras["radius"] == core.radius and "radius" not in measure(m, (0, 0), "colour", palm_area=2000.0).extras
    )
    (found,) = region_detections(m, (0, 0), "colour", palm_area=2000.0, core=True)
    assert found.measurement.extras["radius"] == core.radius
    halved = measure(np.ascontiguousarray(m[::2, ::2]), (0, 0), "colour", palm_area=2000.0, step=2, core=True)
    assert halved.extras["radius"] == pytest.approx(25.0, abs=2.0)  # every other row and column: full-resolution px


def test_split_parts_with_core_are_the_palm_centres_not_pulled_up_the_forearms():
    from fusion_pf.cues.regions import split_region

    yy, xx = np.mgrid[:200, :200]
    m = np.zeros((200, 200), bool)
    for cx in (75, 125):  # two joined palms side by side (radius 25, 50 px apart) ...
        m |= (xx - cx) ** 2 + (yy - 120) ** 2 <= 25**2
    m[20:120, 60:70] = m[20:120, 130:140] = True  # ... each with its forearm running up
    seeds = np.array([[75.0, 120.0], [125.0, 120.0]])
    plain = split_region(m, seeds)
    core = split_region(m, seeds, core=True)
    assert plain is not None and core is not None
    assert all(120 - p.v > 15 for p in plain)  # the centroids lie up the forearms
    assert [(p.u, p.v) for p in core] == [pytest.approx((75, 120), abs=1.0), pytest.approx((125, 120), abs=1.0)]
    assert [(p.area, p.bbox) for p in core] == [(p.area, p.bbox) for p in plain]


@pytest.mark.parametrize("seed", range(12))
def test_region_statistics_equal_scipy_labelling(seed):
    # every region's area, box, centroid and core centre against an independent labelling (scipy.ndimage),
    # on masks whose regions lie anywhere in a larger window (the statistics run on their bounding box)
    from scipy import ndimage

    from fusion_pf.cues.regions import core_centre

    rng = np.random.default_rng(seed)
    h, w = rng.integers(20, 120, size=2)
    m = _mask(h, w)
    y0, x0 = rng.integers(0, h - 10), rng.integers(0, w - 10)
    y1, x1 = rng.integers(y0 + 5, h + 1), rng.integers(x0 + 5, w + 1)
    m[y0:y1, x0:x1] = np.where(rng.random((y1 - y0, x1 - x0)) < rng.uniform(0.2, 0.9), np.uint8(255), np.uint8(0))
    labels, n = ndimage.label(m > 0, structure=np.ones((3, 3)))
    if n == 0:
        return
    boxes = ndimage.find_objects(labels)
    areas = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    big = int(np.argmax(areas))  # the first of the largest, in raster order as OpenCV numbers them
    sl = boxes[big]
    want_box = (sl[1].start, sl[0].start, sl[1].stop - sl[1].start, sl[0].stop - sl[0].start)
    ys, xs = np.nonzero(labels == big + 1)
    for core in (False, True):
        r = largest_region(m, core=core)
        assert r is not None and (r.area, r.bbox) == (areas[big], want_box)
        if core:
            cu, cv, _ = core_centre(labels[sl] == big + 1)
            want = (cu + want_box[0], cv + want_box[1])
        else:
            want = (xs.mean(), ys.mean())
        assert (r.u, r.v) == pytest.approx(want, abs=1e-9)
    dets = region_detections(m, (7, 3), "colour", palm_area=100.0, max_regions=n)
    got = sorted((d.measurement.extras["area"], *d.measurement.extras["bbox"]) for d in dets)
    want_all = sorted(
        (int(areas[i]), b[1].start + 7, b[0].start + 3, b[1].stop - b[1].start, b[0].stop - b[0].start)
        for i, b in enumerate(boxes)
    )
    assert got == want_all


def test_two_means_splits_two_discs_from_poor_seeds_and_halves_one_blob():
    # two abutting unit discs, rotated: started at poor seeds (half a radius off each centre, toward the other),
    # the means converge to the discs (every point of each disc on its own side; the tangent point may go either way)
    grid = np.mgrid[-1:1:201j, -1:1:201j].reshape(2, -1).T
    disc = grid[(grid**2).sum(axis=1) < 1.0]
    turn = np.array([[0.6, -0.8], [0.8, 0.6]])
    two = np.concatenate([disc, disc + [2.0, 0.0]]) @ turn.T
    first = two_means(two, np.array([[0.5, 0.0], [1.5, 0.0]]) @ turn.T)
    assert first is not None
    assert first[: len(disc)].all() and not first[len(disc) :].any()
    # the seeds' order names the parts
    swapped = two_means(two, np.array([[1.5, 0.0], [0.5, 0.0]]) @ turn.T)
    assert swapped is not None and np.array_equal(swapped, ~first)
    # one disc started at two points on a diameter: split at the perpendicular diameter, half each
    halves = two_means(disc, np.array([[-0.3, 0.0], [0.3, 0.0]]))
    assert halves is not None
    assert np.array_equal(halves, disc[:, 0] <= 0.0) or np.array_equal(halves, disc[:, 0] < 0.0)
    # seeds that put every point on one side: None
    assert two_means(disc, np.array([[0.0, 0.0], [5.0, 0.0]])) is None
