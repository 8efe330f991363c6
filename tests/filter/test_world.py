"""The world filter's maths (fusion_pf.filter.world): projection, line-of-sight triangulation, the 3-D particle filter."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from fusion_pf.errors import InputError
from fusion_pf.filter.likelihood import robust_loglik
from fusion_pf.filter.world import (
    OUTLIER_RANGE_MM,
    OUTLIER_VOLUME_MM3,
    Exclusion,
    PixelObservation,
    PointObservation,
    RangeObservation,
    SizeObservation,
    WorldParticleFilter,
    beyond,
    closest_point,
    in_view,
    measured_point,
    normalised,
    off_line_mm,
    project,
    range_loglik,
    ray,
    size_depth,
    size_loglik,
)
from fusion_pf.frame import Intrinsics
from fusion_pf.rig import CameraPose

K = Intrinsics(fx=249.6, fy=249.6, cx=79.5, cy=49.5, width=160, height=100)
LEFT = CameraPose.from_rvec([0.02, 0.45, -0.01], [-900.0, 20.0, -1500.0])
RIGHT = CameraPose.from_rvec([-0.03, -0.5, 0.02], [1000.0, -40.0, -1400.0])
POINT = np.array([60.0, 35.0, 250.0])


def test_project_matches_opencv():
    pts = POINT + np.random.default_rng(0).normal(0, 200, (20, 3))
    for pose in (LEFT, RIGHT):
        uv, z = project(pts, pose, K)
        w2c = pose.inverse()
        ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(w2c.rotation)[0], w2c.translation_mm, K.K, None)
        assert uv == pytest.approx(ref.reshape(-1, 2), abs=1e-9)
        assert z == pytest.approx(pose.to_camera(pts)[:, 2], abs=1e-9)
    behind, _ = project(LEFT.translation_mm - 100 * LEFT.rotation[:, 2], LEFT, K)
    assert np.isnan(behind).all() and not in_view(behind, K)[0]


def test_normalised_matches_opencv_undistort_points():
    uv = np.array([[0.0, 0.0], [79.5, 49.5], [151.25, 3.5], [17.0, 88.0]])
    ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), K.K, None).reshape(-1, 2)
    assert np.array([normalised(p, K) for p in uv]) == pytest.approx(ref, abs=1e-12)


def test_off_line_mm_is_the_cross_product_distance():
    rng = np.random.default_rng(3)
    pts = rng.normal(0, 500, (30, 3))
    origin, d = rng.normal(0, 300, 3), rng.normal(0, 1, 3)
    d /= np.linalg.norm(d)
    ref = np.linalg.norm(np.cross(pts - origin, d), axis=1)  # |r x d| = |r| sin(angle)
    assert off_line_mm(pts, origin, d) == pytest.approx(ref, rel=1e-12)


def test_beyond_moves_the_point_away_from_the_origin_on_its_line():
    origin, x = np.array([100.0, -50.0, -1500.0]), np.array([40.0, 30.0, 200.0])
    moved = beyond(x, origin, 20.0)
    assert np.linalg.norm(moved - origin) == pytest.approx(np.linalg.norm(x - origin) + 20.0, abs=1e-9)
    assert np.linalg.norm(np.cross(moved - origin, x - origin)) == pytest.approx(0.0, abs=1e-6)
    assert np.linalg.norm(beyond(moved, origin, -20.0) - x) == pytest.approx(0.0, abs=1e-9)


def test_a_pixel_weighs_particles_by_their_distance_in_mm_from_its_line_whatever_their_depth():
    # two particles 15 mm off the pixel's line of sight, one 600 mm farther along it: the same likelihood (a
    # reprojection error in px favoured the far one, 15 mm being fewer pixels there)
    uv = project(POINT[None], LEFT, K)[0][0]
    o, d = _line(LEFT, uv)
    side = np.cross(d, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    pf = WorldParticleFilter(3, (10.0, 2.5), 0)
    pf.particles[:, :3] = [POINT + 15 * side, POINT + 600 * d + 15 * side, POINT + 40 * side]
    ll = pf.log_likelihood([PixelObservation(uv, 20.0, LEFT, K)])
    assert ll[0] == pytest.approx(ll[1], abs=1e-9) and ll[2] < ll[0] - 1.0


def test_a_detection_two_joined_targets_share_measures_their_midpoint():
    # one blob of two joined hands: it lies between them, so the target is where the blob is the midpoint of it and
    # its partner (the mirror of the partner about the blob), not on the blob
    blob, partner = np.array([0.0, 0.0, 0.0]), np.array([-60.0, 10.0, 5.0])
    x = np.array([blob, 2 * blob - partner, blob + [25.0, -5.0, 40.0]])
    assert measured_point(x, partner) == pytest.approx((x + partner) / 2)
    assert measured_point(x, None) is not None and measured_point(x, None) == pytest.approx(x)
    pf = WorldParticleFilter(3, (10.0, 2.5), 0)
    pf.particles[:, :3] = x
    ll = pf.log_likelihood([PointObservation(blob, 20.0, partner)])
    d2 = (((x + partner) / 2 - blob) ** 2).sum(axis=1)
    ref = np.log(0.9 * np.exp(-d2 / (2 * 20.0**2)) / (2 * math.pi * 20.0**2) ** 1.5 + 0.1 / OUTLIER_VOLUME_MM3)
    assert ll == pytest.approx(ref, rel=1e-12) and int(np.argmax(ll)) == 1
    # a pixel shared the same way: the best particle is the one whose midpoint with the partner is on the line
    uv = project(POINT[None], LEFT, K)[0][0]
    pf.particles[:, :3] = [POINT, 2 * POINT - partner, POINT + [30.0, 0.0, 0.0]]
    assert int(np.argmax(pf.log_likelihood([PixelObservation(uv, 20.0, LEFT, K, partner)]))) == 1


def _line(pose, uv):
    xy = (np.asarray(uv) - [K.cx, K.cy]) / [K.fx, K.fy]
    return ray(xy, pose)


def test_closest_point_recovers_a_point_seen_by_two_cameras():
    lines = [_line(pose, project(POINT[None], pose, K)[0][0]) for pose in (LEFT, RIGHT)]
    point, dist = closest_point(np.array([o for o, _ in lines]), np.array([d for _, d in lines]))
    assert np.abs(point - POINT).max() < 1e-6
    assert dist.max() < 1e-6


def test_closest_point_of_two_skew_lines_is_the_papers_midpoint():
    # paper 004 eq. 22-23, solved independently: [v1, -v2] c = p2 - p1 in the least-squares sense
    # (the common perpendicular's feet), Z = (p1 + c1 v1 + p2 + c2 v2) / 2, eq. 24: half their gap
    rng = np.random.default_rng(3)
    uv1 = project(POINT[None], LEFT, K)[0][0] + rng.normal(0, 2, 2)
    uv2 = project(POINT[None], RIGHT, K)[0][0] + rng.normal(0, 2, 2)
    (p1, v1), (p2, v2) = _line(LEFT, uv1), _line(RIGHT, uv2)
    c = np.linalg.lstsq(np.c_[v1, -v2], p2 - p1, rcond=None)[0]
    a, b = p1 + c[0] * v1, p2 + c[1] * v2
    point, dist = closest_point(np.array([p1, p2]), np.array([v1, v2]))
    assert point == pytest.approx((a + b) / 2, abs=1e-6)
    assert dist == pytest.approx([np.linalg.norm(a - b) / 2] * 2, abs=1e-6)
    assert 1.0 < np.linalg.norm(point - POINT) < 60.0  # 2 px of noise at 2 m


def test_closest_point_refuses_one_line_and_parallel_lines():
    with pytest.raises(InputError, match="M >= 2"):
        closest_point(np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(InputError, match="parallel"):
        closest_point(np.array([[0.0, 0, 0], [10.0, 0, 0]]), np.array([[0.0, 0, 1], [0.0, 0, 1]]))


def test_robust_loglik_in_three_dimensions_is_the_mixture_density():
    d2 = np.array([0.0, 100.0, 2500.0, 1e6])
    sigma, eps, volume = 20.0, 0.1, 1e9
    ref = np.log((1 - eps) * np.exp(-d2 / (2 * sigma**2)) / (2 * math.pi * sigma**2) ** 1.5 + eps / volume)
    assert robust_loglik(d2.copy(), sigma, eps, volume, dims=3) == pytest.approx(ref, rel=1e-12)


def _run(observe, frames=30, seed=0):
    pf = WorldParticleFilter(300, (10.0, 2.5), seed)
    pf.reset(POINT + [80.0, -60.0, 90.0], 60.0)
    for k in range(frames):
        pf.predict(k * 33_333_333)
        pf.update(observe())
    return pf.estimate()


def test_points_hold_the_target():
    rng = np.random.default_rng(1)
    est, spread = _run(lambda: [PointObservation(POINT + rng.normal(0, 10, 3), 10.0)])
    assert np.linalg.norm(est - POINT) < 12.0 and spread < 30.0


def test_two_colour_only_cameras_triangulate_the_target():
    # pixels alone (no depth anywhere): two lines of sight fix the depth as well
    rng = np.random.default_rng(2)

    def observe():
        out = []
        for pose in (LEFT, RIGHT):
            uv = project(POINT[None], pose, K)[0][0] + rng.normal(0, 1.0, 2)
            out.append(PixelObservation(uv, 20.0, pose, K))  # 20 mm: about 3 px at 1.7 m
        return out

    est, _ = _run(observe)
    assert np.linalg.norm(est - POINT) < 15.0


def test_one_colour_only_camera_leaves_the_depth_where_it_was():
    # the same pixels of one camera only: the estimate moves onto the line of sight, and along it stays about
    # where it started (a noise per particle, sigma fx / z_i, carried it 590 mm away from the camera)
    start = POINT + [80.0, -60.0, 90.0]

    def observe():
        return [PixelObservation(project(POINT[None], LEFT, K)[0][0], 20.0, LEFT, K)]

    est, _ = _run(observe)
    o, d = _line(LEFT, project(POINT[None], LEFT, K)[0][0])
    assert np.linalg.norm(np.cross(est - o, d)) < 15.0
    assert abs(np.dot(est - start, d)) < 100.0  # measured 44 mm


def test_range_loglik_is_the_one_dimensional_mixture_of_the_distance_from_the_shell():
    centre, radius, sigma, eps = np.array([10.0, -20.0, 300.0]), 250.0, 15.0, 0.1
    points = centre + np.array([[250.0, 0, 0], [0, 270.0, 0], [0, 0, -100.0], [0, 0, 1250.0]])
    d = np.array([0.0, 20.0, -150.0, 1000.0])
    ref = np.log(
        (1 - eps) * np.exp(-(d**2) / (2 * sigma**2)) / math.sqrt(2 * math.pi * sigma**2) + eps / OUTLIER_RANGE_MM
    )
    assert range_loglik(points, RangeObservation(centre, radius, sigma), eps) == pytest.approx(ref, rel=1e-12)


def test_a_range_from_a_joint_fixes_the_depth_along_one_line_of_sight():
    # one colour-only camera's pixel and the target's distance (300 mm) from a point 45 degrees off the line of sight
    # (an elbow): the estimate goes to where the line crosses that shell, the pixel alone leaves it where it started
    uv = project(POINT[None], LEFT, K)[0][0]
    o, d = _line(LEFT, uv)
    side = np.cross(d, [0.0, 1.0, 0.0])
    elbow = POINT + 300.0 * (d + side / np.linalg.norm(side)) / math.sqrt(2.0)
    along = {}
    for name, extra in (("pixel", []), ("pixel and range", [RangeObservation(elbow, 300.0, 15.0)])):
        est, _ = _run(lambda extra=extra: [PixelObservation(uv, 20.0, LEFT, K), *extra])
        along[name] = abs(float(np.dot(est - POINT, d)))
        assert np.linalg.norm(np.cross(est - o, d)) < 15.0
    assert along["pixel"] > 80.0  # measured 137 mm
    assert along["pixel and range"] < 15.0


def _disc(centre_mm, radius_mm, pose, n=360):
    """The rim of a disc facing ``pose``'s camera (in the plane of its image) in the world, ``(n, 3)``."""
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return centre_mm + radius_mm * (np.outer(np.cos(a), pose.rotation[:, 0]) + np.outer(np.sin(a), pose.rotation[:, 1]))


def _opencv_pixels(points_mm, pose, intrinsics=K):
    w2c = pose.inverse()
    ref, _ = cv2.projectPoints(points_mm, cv2.Rodrigues(w2c.rotation)[0], w2c.translation_mm, intrinsics.K, None)
    return ref.reshape(-1, 2)


def test_size_depth_is_the_depth_of_a_disc_of_that_size_projected_by_opencv():
    # a 50 mm disc facing the camera off its axis at several depths, projected by OpenCV: its image radius gives back
    # the depth (pinhole: a circle of radius fx R / z about the centre's image)
    o, d = _line(LEFT, np.array([25.0, 70.0]))
    for depth in (600.0, 1500.0, 3200.0):
        centre = o + d * depth / float(d @ LEFT.rotation[:, 2])  # the point of that depth on the line
        rim = _opencv_pixels(_disc(centre, 50.0, LEFT), LEFT)
        radius_px = np.linalg.norm(rim - _opencv_pixels(centre[None], LEFT)[0], axis=1)
        assert radius_px.std() < 1e-9 * radius_px.mean()  # a circle
        assert size_depth(50.0, float(radius_px.mean()), K.fx) == pytest.approx(depth, rel=1e-9)


def test_a_colour_regions_radius_gives_the_depth_of_a_drawn_disc():
    # the disc drawn (OpenCV's filled polygon of the projected rim, 1/16 px), measured as a colour region with a core
    # centre: its inscribed radius is the disc's within the pixel grid, and so is the depth it gives
    from fusion_pf.cues.regions import measure

    big = Intrinsics(fx=499.2, fy=499.2, cx=319.5, cy=199.5, width=640, height=400)
    pose = CameraPose.from_rvec([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    for depth in (700.0, 1100.0, 1600.0):
        rim = _opencv_pixels(_disc(np.array([-90.0, 40.0, depth]), 50.0, pose), pose, big)
        mask = np.zeros((big.height, big.width), np.uint8)
        cv2.fillPoly(mask, [np.round(rim * 16).astype(np.int32)], 255, shift=4)
        m = measure(mask, (0, 0), "colour", palm_area=1000.0, core=True)
        assert m is not None
        assert size_depth(50.0, float(m.extras["radius"]), big.fx) == pytest.approx(depth, rel=0.03)


def test_size_loglik_is_the_one_dimensional_mixture_of_the_size_a_particle_implies():
    # points on a line of sight at known depths: a particle at depth z implies the size size_px z / fx (mm)
    size_px, size_mm, sigma, eps = 12.0, 50.0, 4.0, 0.1
    o, d = _line(LEFT, np.array([60.0, 30.0]))
    depths = np.array([900.0, 1040.0, 1200.0, 2500.0])
    points = o + np.outer(depths / float(d @ LEFT.rotation[:, 2]), d)
    r = size_px * depths / K.fx - size_mm
    ref = np.log(
        (1 - eps) * np.exp(-(r**2) / (2 * sigma**2)) / math.sqrt(2 * math.pi * sigma**2) + eps / (2.0 * size_mm)
    )
    ob = SizeObservation(size_px, size_mm, sigma, LEFT, K)
    assert size_loglik(points, ob, eps) == pytest.approx(ref, rel=1e-12)
    behind = o - 500.0 * LEFT.rotation[:, 2]
    assert size_loglik(behind[None], ob, eps)[0] == pytest.approx(math.log(eps / (2.0 * size_mm)))


def test_an_apparent_size_fixes_the_depth_along_one_line_of_sight():
    # one colour-only camera's pixel and the target's apparent size (its 50 mm seen as fx 50 / z px): the estimate goes
    # to that depth on the line, the pixel alone leaves it where it started
    uv = project(POINT[None], LEFT, K)[0][0]
    o, d = _line(LEFT, uv)
    z = float(LEFT.to_camera(POINT[None])[0, 2])
    along = {}
    for name, extra in (("pixel", []), ("pixel and size", [SizeObservation(K.fx * 50.0 / z, 50.0, 2.0, LEFT, K)])):
        est, _ = _run(lambda extra=extra: [PixelObservation(uv, 20.0, LEFT, K), *extra])
        along[name] = abs(float(np.dot(est - POINT, d)))
        assert np.linalg.norm(np.cross(est - o, d)) < 15.0
    assert along["pixel"] > 80.0  # measured 137 mm
    assert along["pixel and size"] < 15.0


def test_predict_scales_the_process_noise():
    # the same draws: a half noise scale moves every particle half as far (no velocity yet, so the noise only)
    moved = []
    for scale in (1.0, 0.5):
        pf = WorldParticleFilter(50, (10.0, 2.5), 7)
        pf.reset(POINT, 0.0)
        pf.predict(0)
        pf.predict(33_333_333, scale)
        moved.append(pf.particles - np.concatenate([POINT, np.zeros(3)]))
    assert np.abs(moved[0]).mean() > 1.0
    assert moved[1] == pytest.approx(0.5 * moved[0], abs=1e-9)


def test_reseed_redraws_a_share_of_the_particles_around_the_point_and_keeps_the_weights_normalised():
    pf = WorldParticleFilter(200, (10.0, 2.5), 3)
    pf.reset(POINT, 5.0)
    far = POINT + [300.0, 0.0, 0.0]
    pf.reseed(far, 5.0, np.array([30.0, 0.0, 0.0]), fraction=0.25)
    moved = np.linalg.norm(pf.particles[:, :3] - far, axis=1) < 30.0
    assert moved.sum() == 50
    assert np.all((pf.particles[moved, 3] >= 0.0) & (pf.particles[moved, 3] <= 30.0))
    assert np.all(pf.particles[~moved, 3:] == 0.0)
    assert np.exp(pf.log_weights).sum() == pytest.approx(1.0)
    with pytest.raises(InputError, match="fraction"):
        pf.reseed(far, 5.0, fraction=1.5)


def test_a_reseeded_filter_follows_a_jump_the_process_noise_does_not():
    # the target jumps 300 mm (several times the process noise): measured by points there, the plain filter's
    # particles cannot reach it (the outlier term keeps them); re-seeded they follow within a few instants
    jump = POINT + [300.0, -100.0, 50.0]
    errors = []
    for reseed in (False, True):
        pf = WorldParticleFilter(300, (10.0, 2.5), 4)
        pf.reset(POINT, 10.0)
        for k in range(5):
            pf.predict(k * 33_333_333)
            if reseed and k == 0:
                pf.reseed(jump, 20.0)
            pf.update([PointObservation(jump, 20.0), PointObservation(jump + 5.0, 20.0)])
        errors.append(float(np.linalg.norm(pf.estimate()[0] - jump)))
    assert errors[0] > 200.0 and errors[1] < 20.0


def test_exclusion_potential_is_zero_beyond_the_distance_and_penalises_the_offset_across_the_axis():
    # hand-computed: -((min - d)^+)^2 / (2 s^2) - |r_perp|^2 / (2 s_axis^2)
    partner = np.array([100.0, 0.0, 1000.0])
    ex = Exclusion(partner, 30.0, 5.0)
    points = partner + np.array([[40.0, 0.0, 0.0], [20.0, 0.0, 0.0], [0.0, 0.0, 10.0]])
    assert ex.log_potential(points) == pytest.approx([0.0, -0.5 * (10.0 / 5.0) ** 2, -0.5 * (20.0 / 5.0) ** 2])
    along = Exclusion(partner, 30.0, 5.0, np.array([1.0, 0.0, 0.0]), 40.0)
    points = partner + np.array([[60.0, 0.0, 0.0], [40.0, 30.0, 0.0], [40.0, 0.0, -20.0]])
    assert along.log_potential(points) == pytest.approx([0.0, -0.5 * (30.0 / 40.0) ** 2, -0.5 * (20.0 / 40.0) ** 2])


def test_an_excluded_target_keeps_its_side_of_a_partner_its_evidence_pulls_it_onto():
    # a joined hand whose only evidence is pulled next to its partner (a skeleton joint dragged toward the pair's
    # middle, 10 mm off it): alone the filter sits there; excluded from the partner with the axis the pair combined
    # along, it stays a hand's thickness away along that axis
    partner = POINT + np.array([-45.0, 0.0, 0.0])
    axis = np.array([1.0, 0.0, 0.0])
    pulled = partner + [10.0, 0.0, 0.0]
    ends = []
    for exclusions in ((), (Exclusion(partner, 30.0, 5.0, axis, 40.0),)):
        pf = WorldParticleFilter(300, (10.0, 2.5), 5)
        pf.reset(POINT, 5.0)
        for k in range(30):
            pf.predict(k * 33_333_333)
            pf.update([PointObservation(pulled, 30.0)], exclusions)
        ends.append(pf.estimate()[0] - partner)
    assert np.linalg.norm(ends[0] - (pulled - partner)) < 8.0
    r = ends[1]
    assert r @ axis > 25.0 and np.linalg.norm(r - (r @ axis) * axis) < 10.0
