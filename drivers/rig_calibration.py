"""Calibrate a rig's camera poses: a ChArUco board seen by the cameras, refined by coloured ICP of their depth.

1. **Board.** In every frame set each camera's image is searched for the board
   (:func:`drivers.charuco.detect`); a camera's pose in the board frame
   (= ``world``) is one PnP fit over all its detections (the board and the
   cameras are static), with its reprojection error.
2. **Depth (optional).** Where cameras have depth, each camera's point cloud of
   the static scene (the per-pixel median of its background frames' depth, or
   of all frames when there are none) is registered to the reference camera's
   (the one with the smallest reprojection error) by open3d's coloured ICP
   (Park et al. 2017), coarse to fine, starting from the board pose (or from a
   given initial pose). ICP minimises its own residual, so that residual cannot
   judge it; the board can. A refined pose is accepted only when

   * its fitness (the share of the camera's points with a partner in the
     reference's cloud at the finest level) is at least :data:`ICP_MIN_FITNESS`;
   * it reprojects the camera's board corners better than the pose ICP started
     from (when that is not the board pose itself); and
   * it is consistent with the board: the increase of the board's sum of squared
     reprojection residuals over the board pose's, in units of the board fit's
     residual variance (``SSR / (2N - 6)``), is at most :data:`ICP_BOARD_CHI2`
     (the 99 % point of chi-square with 6 degrees of freedom: a likelihood-ratio
     test of the 6 pose parameters). ICP may thus move a pose only where the
     board leaves it uncertain (a small or distant board), never away from a
     precise board fit.

   Otherwise the board pose stays; either way the fitness, inlier RMSE, the move
   and the board chi-square are reported per camera pair.

On the synthetic calibration sequences (``synth --cameras N --board``, 640 x 400,
realistic depth; N = 2-4, seeds 1-8) the board alone recovers every pose within
3.2 mm and 0.10 degrees. Coloured ICP of the static scene converges to the same
pose from the board pose, from the true pose and from poses 20 mm / 2 degrees off
(3 cameras, seed 3): 1.5 mm / 0.06 degrees from the truth for one pair, but
29.8 mm / 0.13 degrees for the pair sharing the least structure (it slides along
the room's planes; fitness 0.29); on seeds 1, 2 and 4 it lands 2.5-141 mm off. The
board test rejects every one of these (docs/recording-format.md gives the figures), so
on synthetic rigs the kept poses are the board's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, Intrinsics
from fusion_pf.rig import CameraPose

from .charuco import BoardPose, BoardSpec, Detection, camera_pose, detect, reprojection_error

if TYPE_CHECKING:  # the command line imports this module for its choices: keep it light
    from .rig import RigReplay

#: Voxel sizes (mm) of the coarse-to-fine coloured ICP; the correspondence distance is twice the voxel.
ICP_VOXELS_MM = (40.0, 20.0, 10.0)
#: Iterations per ICP level.
ICP_ITERATIONS = 50
#: Refinement methods.
REFINEMENTS = ("none", "icp")
#: Smallest ICP fitness (share of the camera's points with a partner at the finest level) to accept a refinement.
ICP_MIN_FITNESS = 0.25
#: Largest board chi-square of an accepted refinement: the 99 % point of chi-square with 6 degrees of freedom.
ICP_BOARD_CHI2 = 16.81


@dataclass(frozen=True)
class IcpResult:
    """What coloured ICP did to a camera's pose (from the pose it started at), and the verdict of the board."""

    fitness: float  # fraction of the camera's points with a correspondence at the finest level
    inlier_rmse_mm: float
    moved_mm: float
    turned_deg: float
    board_rms_px: float = math.nan  # the board's reprojection error (RMS) with the refined pose
    board_chi2: float = math.nan  # increase of the board's squared residuals over the board pose's / their variance
    accepted: bool = True
    reason: str = ""  # why it was rejected
    reference: str = ""  # the camera it was registered to


@dataclass(frozen=True)
class CameraResult:
    """A calibrated camera: its final pose, the board fit, the ICP refinement (None: not refined) and ICP's pose."""

    pose: CameraPose
    board: BoardPose
    icp: IcpResult | None = None
    reference: bool = False
    icp_pose: CameraPose | None = None  # where ICP put the camera, kept (icp.accepted) or not


def _static_frame(frames: list[Frame]) -> Frame | None:
    """One frame whose depth is the per-pixel median of the valid depths of ``frames`` (None without depth)."""
    depths = [f.depth for f in frames if f.depth is not None]
    if not depths:
        return None
    stack = np.stack(depths).astype(np.float32)
    stack[stack == 0] = np.nan
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels: no depth there
            median = np.nanmedian(stack, axis=0)
    depth = np.nan_to_num(np.rint(median), nan=0.0).astype(np.uint16)
    return dataclasses.replace(frames[0], depth=depth)


def _cloud(frame: Frame, pose: CameraPose | None = None):  # -> open3d PointCloud
    import open3d as o3d

    from fusion_pf.geometry import roi_points

    h, w = frame.depth.shape  # type: ignore[union-attr]
    points, colours = roi_points(frame, (0, 0, w, h))
    if pose is not None:
        points = pose.to_world(points)
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(points)
    cloud.colors = o3d.utility.Vector3dVector(colours)
    return cloud


def _matrix(pose: CameraPose) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = pose.rotation, pose.translation_mm
    return out


def refine_icp(
    frame: Frame, initial: CameraPose, target_world, voxels: tuple[float, ...] = ICP_VOXELS_MM
) -> tuple[CameraPose, IcpResult]:
    """Register ``frame``'s cloud to ``target_world`` (an open3d cloud in world mm) by coloured ICP from ``initial``.

    ``voxels``: the coarse-to-fine voxel sizes (mm); the correspondence distance is twice each.
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    source = _cloud(frame)
    transform = _matrix(initial)
    result = None
    for voxel in voxels:
        src = source.voxel_down_sample(voxel)
        dst = target_world.voxel_down_sample(voxel)
        for cloud in (src, dst):
            cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.0 * voxel, max_nn=30))
        result = reg.registration_colored_icp(
            src,
            dst,
            2.0 * voxel,
            transform,
            reg.TransformationEstimationForColoredICP(),
            reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=ICP_ITERATIONS),
        )
        transform = np.asarray(result.transformation)
    assert result is not None
    rotation = transform[:3, :3]
    u, _s, vt = np.linalg.svd(rotation)  # re-orthonormalise the float result
    pose = CameraPose(u @ vt, transform[:3, 3])
    moved, turned = pose.error_to(initial)
    return pose, IcpResult(float(result.fitness), float(result.inlier_rmse), moved, turned)


def board_chi2(detections: list[Detection], k: Intrinsics, board: BoardPose, pose: CameraPose) -> tuple[float, float]:
    """The board's RMS reprojection error (px) with ``pose``, and its chi-square against the board fit.

    ``(SSR(pose) - SSR(board)) / s2`` with ``SSR = rms^2 N`` over the N corners and
    ``s2 = SSR(board) / (2N - 6)`` the residual variance of the board fit: the
    likelihood-ratio statistic of ``pose`` against the board's own optimum (module docstring).
    """
    rms, _worst = reprojection_error(detections, k, pose)
    n = board.corners
    variance = max(board.rms_px**2 * n / max(2 * n - 6, 1), 1e-12)
    return rms, (rms**2 - board.rms_px**2) * n / variance


def calibrate(
    rig: RigReplay,
    spec: BoardSpec,
    *,
    refine: str = REFINEMENTS[0],
    initial: Mapping[str, CameraPose] | None = None,
    voxels: tuple[float, ...] = ICP_VOXELS_MM,
) -> dict[str, CameraResult]:
    """Every camera's pose in the board's frame (module docstring).

    ``initial``: poses (in the board's frame) ICP starts from instead of the board poses, by camera;
    ``voxels``: the coarse-to-fine ICP voxel sizes (mm).

    Raises
    ------
    InputError
        When a camera never sees the board (naming it and how many frames it had).
    """
    if refine not in REFINEMENTS:
        raise InputError(f"refine must be one of {', '.join(REFINEMENTS)}, got {refine!r}")
    import cv2

    detector = cv2.aruco.CharucoDetector(spec.board())
    found: dict[str, list[Detection]] = {name: [] for name in rig.cameras}
    frames: dict[str, int] = dict.fromkeys(rig.cameras, 0)
    static: dict[str, list[Frame]] = {name: [] for name in rig.cameras}
    moving: dict[str, list[Frame]] = {name: [] for name in rig.cameras}
    for frameset in rig:
        for name, view in frameset.views.items():
            frames[name] += 1
            seen = detect(spec, view.frame.color, detector)
            if seen is not None:
                found[name].append(seen)
            (static if frameset.background else moving)[name].append(view.frame)
    missing = [f"{name} (0 of {frames[name]} frames)" for name, d in found.items() if not d]
    if missing:
        raise InputError(
            f"the board ({spec.squares[0]}x{spec.squares[1]} squares of {spec.square_mm:g} mm, {spec.dictionary}) "
            f"was not found by camera {', '.join(missing)}; its pose cannot be calibrated"
        )
    boards, intrinsics = {}, {}
    for name in rig.cameras:
        intrinsics[name] = next(iter(static[name] or moving[name])).intrinsics
        boards[name] = camera_pose(found[name], intrinsics[name])
    results = {name: CameraResult(b.pose, b) for name, b in boards.items()}
    if refine == "none":
        return results
    scenes = {name: _static_frame(static[name] or moving[name]) for name in rig.cameras}
    with_depth = [name for name in rig.cameras if scenes[name] is not None]
    if len(with_depth) < 2:
        return results
    reference = min(with_depth, key=lambda name: boards[name].rms_px)
    target = _cloud(scenes[reference], boards[reference].pose)  # type: ignore[arg-type]
    results[reference] = dataclasses.replace(results[reference], reference=True)
    for name in with_depth:
        if name == reference:
            continue
        board = boards[name]
        start = (initial or {}).get(name, board.pose)
        pose, icp = refine_icp(scenes[name], start, target, voxels)  # type: ignore[arg-type]
        rms, chi2 = board_chi2(found[name], intrinsics[name], board, pose)
        _start_rms, start_chi2 = board_chi2(found[name], intrinsics[name], board, start)
        reasons = []
        if icp.fitness < ICP_MIN_FITNESS:
            reasons.append(f"fitness {icp.fitness:.2f} < {ICP_MIN_FITNESS:g}")
        if start is not board.pose and chi2 >= start_chi2:
            reasons.append("reprojects the board no better than its start")
        if chi2 > ICP_BOARD_CHI2:
            reasons.append(f"board chi-square {chi2:.0f} > {ICP_BOARD_CHI2:g}")
        icp = dataclasses.replace(
            icp, board_rms_px=rms, board_chi2=chi2, accepted=not reasons, reason="; ".join(reasons), reference=reference
        )
        results[name] = CameraResult(pose if icp.accepted else board.pose, board, icp, icp_pose=pose)
    return results


def report_lines(results: Mapping[str, CameraResult]) -> list[str]:
    """One line per camera: the reprojection error, corners and views; the ICP correction."""
    width = max(len(name) for name in results)
    lines = []
    for name, r in results.items():
        b = r.board
        line = (
            f"{name:<{width}}  reprojection error {b.rms_px:.3f} px RMS (max {b.max_px:.3f} px) "
            f"over {b.corners} corners in {b.views} frames"
        )
        if r.reference:
            line += "; ICP reference"
        elif r.icp is not None:
            i = r.icp
            verdict = "moved it" if i.accepted else f"REJECTED ({i.reason}): would move it"
            line += (
                f"; coloured ICP to {i.reference} {verdict} {i.moved_mm:.1f} mm / {i.turned_deg:.2f} deg "
                f"(fitness {i.fitness:.2f}, inlier RMSE {i.inlier_rmse_mm:.1f} mm, "
                f"board error {i.board_rms_px:.2f} px, board chi-square {i.board_chi2:.1f})"
            )
        lines.append(line)
    return lines
