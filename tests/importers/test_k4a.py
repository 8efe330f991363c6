"""Azure Kinect .mkv import: the SDK's calibration numbers, registered depth, the CLI, a file without depth."""

import json

import av
import cv2
import numpy as np
import pytest

from drivers.importers import detect, open_import
from drivers.importers.k4a import AzureKinectSource, K4aCalibration
from drivers.importers.registration import DepthRegistration
from drivers.mcap_replay import McapReplay

from .conftest import FIXTURES, error_line, fusion_pf

MKV = FIXTURES / "k4a_recording.mkv"
#: Where the mug stands in the 1280x720 colour image (columns 300-470, rows 430-630 lie on its body).
MUG = (slice(430, 630), slice(300, 470))


@pytest.fixture(scope="module")
def calibration():
    with av.open(str(MKV)) as container:
        text = container.streams.attachments[0].data
    return K4aCalibration.from_json(text, (640, 576), (1280, 720))


@pytest.fixture(scope="module")
def raw_depth():
    with av.open(str(MKV)) as container:
        return next(container.decode(video=1)).to_ndarray().astype(np.uint16)


def test_calibration_reproduces_the_azure_kinect_sdk(calibration):
    # pyk4a tests/unit/test_calibration.py: k4a SDK results for this calibration, NFOV unbinned + 720p
    c = calibration
    point_depth = np.array([1031.4664306640625, 1325.8529052734375, 2117.6611328125])
    assert np.allclose(c.rotation @ point_depth + c.translation_mm, [1000.0, 1500.0, 2000.0], atol=1e-3)
    depth_point = np.array([-122.29087829589844, -45.17741394042969, 243.19528198242188])
    pixel = DepthRegistration._project((c.rotation @ depth_point + c.translation_mm)[None], c.color)
    assert np.allclose(pixel, [[250.0, 300.0]], atol=1e-3)
    # colour pixel (250, 300) at depth 250 mm back-projects to the SDK's 3-D point (OpenCV inverse)
    ray = cv2.undistortPoints(
        np.array([[[250.0, 300.0]]]),
        c.color.K,
        np.asarray(c.color.distortion),
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
    )[0, 0]
    assert np.allclose([ray[0] * 250, ray[1] * 250], [-154.5365753173828, -26.12171173095703], atol=1e-3)
    assert c.depth.width == 640 and c.depth.height == 576 and c.color.distortion_model == "rational_polynomial"


def test_registration_agrees_with_opencv_and_keeps_the_nearest(calibration, raw_depth):
    registered = DepthRegistration(calibration)(raw_depth)
    assert registered.shape == (720, 1280) and registered.dtype == np.uint16
    # an independent path: OpenCV undistortPoints + projectPoints for 2000 random valid depth pixels
    rng = np.random.default_rng(0)
    v, u = np.nonzero(raw_depth)
    pick = rng.choice(len(u), 2000, replace=False)
    u, v = u[pick], v[pick]
    kd, kc = calibration.depth, calibration.color
    rays = cv2.undistortPoints(
        np.stack([u, v], 1).astype(np.float64)[:, None],
        kd.K,
        np.asarray(kd.distortion),
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
    )[:, 0]
    points = np.column_stack([rays, np.ones(len(rays))]) * raw_depth[v, u, None]
    cam = points @ calibration.rotation.T + calibration.translation_mm
    image, _ = cv2.projectPoints(cam[:, None], np.zeros(3), np.zeros(3), kc.K, np.asarray(kc.distortion))
    pu, pv = np.rint(image[:, 0]).astype(int).T
    inside = (pu >= 0) & (pu < 1280) & (pv >= 0) & (pv < 720) & (np.hypot(*rays.T) < calibration.depth_metric_radius)
    got, want = registered[pv[inside], pu[inside]].astype(float), cam[inside, 2]
    # z-buffer: nothing registered is farther than the point landing there; most points are the visible one
    assert np.all((got == 0) | (got <= want + 1.0))
    assert np.mean(np.abs(got - want) <= 2.0) > 0.9


def test_import_end_to_end(tmp_path, calibration):
    assert detect(MKV) == "k4a"
    out = tmp_path / "k4a.mcap"
    proc = fusion_pf("import", MKV, out, "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "depth track NFOV_UNBINNED 640x576 registered to colour" in proc.stdout
    assert "tracks not imported: IR, IMU" in proc.stdout
    coverage = float(proc.stdout.split("registered depth covers ")[1].split(" %")[0])
    print(f"registered-depth coverage of the colour image: {coverage:.1f} %")
    assert 45.0 < coverage < 75.0  # the depth camera's NFOV hexagon inside the 720p colour view
    with McapReplay(out) as replay:
        info = replay.info()
        frame = replay.frame(0)
    assert info.frames == 1 and (info.width, info.height) == (1280, 720) and info.missing_skeleton == 1
    assert frame.intrinsics == calibration.color
    assert frame.timestamp_ns == 463_945_000  # Matroska block time 463945 us
    assert "/skeleton/joints" not in {t.topic for t in info.topics}
    mug = frame.depth[MUG]
    assert np.mean(mug > 0) > 0.5
    assert 150 < np.median(mug[mug > 0]) < 450  # a mug a hand's length in front of the camera
    wall = frame.depth[100:300, 350:500]
    assert np.median(wall[wall > 0]) > 2 * np.median(mug[mug > 0])
    info_cmd = fusion_pf("info", out)
    assert info_cmd.returncode == 0 and "1280x720" in info_cmd.stdout and "rational_polynomial" in info_cmd.stdout
    track = fusion_pf("track", out, "-o", tmp_path / "tracked.mcap", "--no-progress")
    assert track.returncode == 0, track.stderr


def test_source_replays_directly(calibration):
    with open_import(MKV) as src:
        frames = list(src)
    assert isinstance(src, AzureKinectSource) and len(frames) == 1 and frames[0].depth is not None
    assert frames[0].color.shape == (720, 1280, 3)


def test_mkv_without_depth_track(tmp_path):
    nodepth = tmp_path / "nodepth.mkv"
    with av.open(str(MKV)) as src, av.open(str(nodepth), "w") as out:
        stream = out.add_stream_from_template(src.streams.video[0])
        stream.metadata.update(src.streams.video[0].metadata)
        for packet in src.demux(src.streams.video[0]):
            if packet.dts is not None:
                packet.stream = stream
                out.mux(packet)
    line = error_line(fusion_pf("import", nodepth, tmp_path / "x.mcap"))
    assert "has no DEPTH track; found COLOR (video, mjpeg 1280x720)" in line


def test_calibration_errors():
    with av.open(str(MKV)) as container:
        text = container.streams.attachments[0].data
    from fusion_pf.errors import RecordingError

    with pytest.raises(RecordingError, match="expected an Azure Kinect depth mode size"):
        K4aCalibration.from_json(text, (600, 500), (1280, 720))
    with pytest.raises(RecordingError, match="is not an Azure Kinect calibration"):
        K4aCalibration.from_json(json.dumps({"foo": 1}), (640, 576), (1280, 720))
