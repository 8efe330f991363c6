"""RMSE, coverage, p95 and BestMax on a small hand-made table (values computed by hand)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion_pf.errors import InputError
from fusion_pf.score.metrics import (
    bestmax,
    bestmax_points,
    frame_errors,
    occlusion_episodes,
    rmse,
    score,
    uncontested_frames,
)

NAN = math.nan

# Five frames. Frame 2 has no reference (skipped by every metric even though
# sources gave points there). Points are chosen so each error is a 3-4-5
# triangle or axis-aligned, i.e. an exact integer.
REFERENCE = [(0, 0), (10, 10), (NAN, NAN), (0, 0), (5, 5)]
POINTS = {
    #           e=5       e=0        skipped   e=2       missing
    "colour": [(3, 4), (10, 10), (1, 1), (0, 2), (NAN, NAN)],
    #           e=6       missing       skipped      e=2       e=3
    "depth": [(0, 6), (NAN, NAN), (NAN, NAN), (2, 0), (5, 8)],
    #            e=10      e=5       skipped   e=3        e=5
    "skeleton": [(6, 8), (13, 14), (0, 0), (0, -3), (8, 9)],
    #          e=1       e=3       skipped   e=4       e=3
    "fused": [(1, 0), (10, 13), (5, 5), (0, 4), (5, 8)],
}
OCCLUDED = [False, True, True, True, False]


def test_frame_errors_are_euclidean_distances():
    e = frame_errors(POINTS["skeleton"], REFERENCE)
    np.testing.assert_allclose(e, [10, 5, NAN, 3, 5])
    e = frame_errors(POINTS["colour"], REFERENCE)
    np.testing.assert_allclose(e, [5, 0, NAN, 2, NAN])


def test_score_by_hand():
    s = score(POINTS, REFERENCE, OCCLUDED)
    m = s.summary
    # RMSE over frames where both exist.
    assert m["colour"].rmse == pytest.approx(math.sqrt((25 + 0 + 4) / 3))
    assert m["depth"].rmse == pytest.approx(math.sqrt((36 + 4 + 9) / 3))
    assert m["skeleton"].rmse == pytest.approx(math.sqrt((100 + 25 + 9 + 25) / 4))
    assert m["fused"].rmse == pytest.approx(math.sqrt((1 + 9 + 16 + 9) / 4))
    # Coverage: 4 reference frames; the colour point on frame 2 does not count.
    assert [m[k].coverage for k in ("colour", "depth", "skeleton", "fused")] == [0.75, 0.75, 1.0, 1.0]
    assert [m[k].n_scored for k in ("colour", "depth", "skeleton", "fused")] == [3, 3, 4, 4]
    # p95 by linear interpolation: skeleton sorted [3, 5, 5, 10], 0.95 * 3 = 2.85
    # -> 5 + 0.85 * (10 - 5) = 9.25; colour sorted [0, 2, 5], 0.95 * 2 = 1.9 -> 2 + 0.9 * 3 = 4.7.
    assert m["skeleton"].p95 == pytest.approx(9.25)
    assert m["colour"].p95 == pytest.approx(4.7)
    assert m["depth"].mean == pytest.approx(11 / 3)
    assert m["skeleton"].max == 10
    # BestMax: f0 fused (1); f1 colour (0); f2 skipped; f3 colour & depth tie at 2;
    # f4 depth & fused tie at 3 -> colour 2, depth 2, skeleton 0, fused 2.
    assert {k: v.bestmax for k, v in m.items()} == {"colour": 2, "depth": 2, "skeleton": 0, "fused": 2}
    np.testing.assert_array_equal(s.bestmax_points["fused"], [1, 0, 0, 0, 1])
    np.testing.assert_array_equal(s.bestmax_points["colour"], [0, 1, 0, 1, 0])
    assert (s.n_frames, s.n_reference, s.n_bestmax_frames, s.n_ties) == (5, 4, 4, 2)
    # Occlusion: flags on rows 1-3, row 2 has no reference -> 2 occluded reference frames,
    # one episode [1, 4). Colour occluded: e 0, 2 -> sqrt(2); visible: only 5.
    assert s.n_occluded == 2
    np.testing.assert_array_equal(s.occlusion_episodes, [[1, 4]])
    assert m["colour"].rmse_occluded == pytest.approx(math.sqrt(2))
    assert m["colour"].rmse_visible == pytest.approx(5)
    assert m["fused"].rmse_occluded == pytest.approx(math.sqrt((9 + 16) / 2))
    assert m["fused"].rmse_visible == pytest.approx(math.sqrt((1 + 9) / 2))


def test_score_without_occlusion_flags_reports_nan_split():
    s = score(POINTS, REFERENCE)
    assert s.n_occluded is None and s.occlusion_episodes.shape == (0, 2)
    assert math.isnan(s.summary["fused"].rmse_occluded)


def test_bestmax_ties_tolerance_and_all_missing_frame():
    errors = {"a": [1.0, NAN, 2.0], "b": [1.0 + 1e-9, NAN, NAN]}
    # Frame 0: within the default 1e-6 px tolerance -> a point each; frame 1: nobody
    # present -> nobody scores; frame 2: b missing, a is alone -> no contest, no point.
    assert bestmax(errors) == {"a": 1, "b": 1}
    assert bestmax(errors, tie_tol=0.0) == {"a": 1, "b": 0}
    np.testing.assert_array_equal(bestmax_points(errors)["b"], [1, 0, 0])
    assert uncontested_frames(errors) == {"a": 1, "b": 0}


def test_rmse_empty_is_nan_and_metrics_nan_without_frames():
    assert math.isnan(rmse([NAN, NAN]))
    assert rmse([3.0, 4.0]) == pytest.approx(math.sqrt(12.5))
    s = score({"fused": [(1, 1)]}, [(NAN, NAN)])
    assert math.isnan(s.summary["fused"].rmse) and math.isnan(s.summary["fused"].coverage)
    assert s.summary["fused"].bestmax == 0


def test_occlusion_episodes():
    np.testing.assert_array_equal(
        occlusion_episodes([True, True, False, True, False, False, True]), [[0, 2], [3, 4], [6, 7]]
    )
    assert occlusion_episodes([False, False]).shape == (0, 2)


@pytest.mark.parametrize(
    "points, reference, message",
    [
        ({"fused": [(1, 2, 3)]}, [(0, 0)], "(n, 2)"),
        ({"fused": [(1, 2), (3, 4)]}, [(0, 0)], "must have 1 rows"),
        ({"fused": [(1, 2)]}, [(0, NAN)], "both finite or both NaN"),
        ({"fused": [(math.inf, 2)]}, [(0, 0)], "infinite"),
        ({}, [(0, 0)], "at least one source"),
    ],
)
def test_bad_inputs_raise_input_error(points, reference, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        score(points, reference)


def test_bestmax_rejects_bad_tolerance_and_ragged_errors():
    with pytest.raises(InputError, match="tie_tol"):
        bestmax({"a": [1.0]}, tie_tol=-1)
    with pytest.raises(InputError, match="one length"):
        bestmax({"a": [1.0], "b": [1.0, 2.0]})


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.one_of(st.none(), st.integers(0, 5)), min_size=4, max_size=4), min_size=1, max_size=20))
def test_bestmax_awards_exactly_the_minimal_present_sources(rows):
    # Integer errors make ties frequent; None is a missing source.
    names = ("a", "b", "c", "d")
    errors = {k: [NAN if r[i] is None else float(r[i]) for r in rows] for i, k in enumerate(names)}
    points = bestmax_points(errors, tie_tol=0.0)
    for t, r in enumerate(rows):
        present = [x for x in r if x is not None]
        for i, k in enumerate(names):
            expected = r[i] is not None and r[i] == min(present) and len(present) >= 2
            assert points[k][t] == expected


def test_uncertainty_coverage_counts_the_errors_within_one_and_two_sigma():
    from fusion_pf.score.metrics import uncertainty_coverage

    # errors 1, 3, 5, 2 against sigma 1, 2, 2, NaN; the last frame has no uncertainty, a NaN error none either
    c = uncertainty_coverage([1.0, 3.0, 5.0, 2.0, NAN], [1.0, 2.0, 2.0, NAN, 1.0])
    assert (c.n, c.within_1, c.within_2) == (3, 1 / 3, 2 / 3)
    empty = uncertainty_coverage([NAN], [1.0])
    assert empty.n == 0 and math.isnan(empty.within_1) and math.isnan(empty.within_2)
    with pytest.raises(InputError, match="one value per frame"):
        uncertainty_coverage([1.0, 2.0], [1.0])
    with pytest.raises(InputError, match=">= 0"):
        uncertainty_coverage([1.0], [-0.5])


def test_score_reports_the_fused_estimates_uncertainty_coverage_only_when_given():
    # fused errors 1, 3, (no reference), 4, 3 against sigma 5, 0.1, 9, 1, 2: within 1 sigma frame 0 only, within 2
    # sigma frames 0 and 4
    s = score(POINTS, REFERENCE, sigma=[5.0, 0.1, 9.0, 1.0, 2.0])
    assert (s.uncertainty.n, s.uncertainty.within_1, s.uncertainty.within_2) == (4, 0.25, 0.5)
    assert score(POINTS, REFERENCE).uncertainty is None
