"""``fusion-pf track MULTI.mcap --serve / --rerun``: the live view of a multi-camera run.

A real Foxglove WebSocket client (the ``websockets`` package) receives every
camera's images under its prefix, the poses on ``/tf`` and ``/tracker/world``
(the very messages of the output file); a real Rerun server (``rerun --save``,
the rerun-sdk wheel's viewer binary) receives the rig in 3-D, read back with
``rerun rrd print``.
"""

import subprocess
import sys
import time
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform

from drivers.tracker_topics import read_json_topic

from ..conftest import CLI, rerun_process
from .test_live import live_serve

TARGETS = "right_hand,left_hand,head"


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    path = tmp_path_factory.mktemp("live_rig") / "rig.mcap"
    cmd = [*CLI, "synth", path, "--cameras", "2", "--hands", "2", "--frames", "24", "--background-frames", "3"]
    r = subprocess.run(
        [str(c) for c in [*cmd, "--size", "160x100", "--seed", "3", "--no-progress"]], capture_output=True
    )
    assert r.returncode == 0, r.stderr
    return path


def test_a_foxglove_client_receives_every_camera_the_poses_and_the_world_estimates(rig, tmp_path):
    port = live_serve.free_port()
    cmd = [*CLI, "track", rig, "-o", tmp_path / "out.mcap", "--targets", TARGETS, "--serve", f"127.0.0.1:{port}"]
    cmd += ["--csv", tmp_path / "out.csv", "--realtime"]
    proc = subprocess.Popen([str(c) for c in cmd], stderr=subprocess.PIPE, text=True)
    topics = ["/cam0/camera/color", "/cam1/camera/color", "/tf", "/tracker/world"]
    client = live_serve.FoxgloveClient(port, topics).start()
    _, err = proc.communicate(timeout=300)
    client.stop()
    assert proc.returncode == 0, err
    assert client.error is None, client.error
    assert "live view for Foxglove at ws://127.0.0.1:" in err and "instant " in err
    # the outputs are those of a run without the live view: a CSV row per tracked instant and target
    assert "right_hand: 21 tracking" in err
    assert len((tmp_path / "out.csv").read_text().splitlines()) == 1 + 21 * 3
    assert client.channels["/cam1/camera/color"]["schemaName"] == "foxglove.CompressedImage"
    assert client.channels["/tracker/world"]["schemaName"] == "fusion_pf.WorldEstimate"
    assert len(client.messages["/cam0/camera/color"]) >= 5 and len(client.messages["/cam1/camera/color"]) >= 5
    children = {FrameTransform.FromString(p).child_frame_id for _, p in client.messages["/tf"]}
    assert children == {"cam0", "cam1"}
    in_file = {t: m for t, m in read_json_topic(tmp_path / "out.mcap", "/tracker/world")}
    live = client.messages["/tracker/world"]
    assert len(live) >= 5
    import json

    for log_time, payload in live:
        assert json.loads(payload) == in_file[log_time]


def test_rerun_receives_every_camera_in_3d_and_the_targets(rig, tmp_path):
    port = live_serve.free_port()
    rerun = Path(sys.executable).with_name("rerun")
    saved = tmp_path / "live.rrd"
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    with rerun_process("--port", port, "--save", saved):
        for _ in range(100):  # the server starts listening
            r = subprocess.run(
                [str(c) for c in [*CLI, "track", rig, "-o", tmp_path / "o.mcap", "--targets", TARGETS, "--force"]]
                # a queue for every instant: the tracker outruns a loaded machine's publisher, which then drops
                + ["--rerun", url, "--no-progress", "--live-queue", "100"],
                capture_output=True,
                text=True,
            )
            if "no Rerun viewer answers" not in r.stderr:
                break
            time.sleep(0.2)
        assert r.returncode == 0, r.stderr
        assert f"live view for Rerun at {url}" in r.stderr and "24 frames published" in r.stderr
        time.sleep(1.0)
    printed = subprocess.run([rerun, "rrd", "print", saved], capture_output=True, text=True, timeout=60)
    assert printed.returncode == 0, printed.stderr
    columns: dict[str, set[str]] = {}
    for line in printed.stdout.splitlines():
        if line.startswith("Chunk(") and " - data columns: [" in line:
            entity, data = line.split(") - ", 1)[1].split(" - data columns: [")
            columns.setdefault(entity, set()).update(data.rstrip("]").split())
    for cam in ("cam0", "cam1"):
        assert {"Transform3D:translation", "Transform3D:mat3x3", "Pinhole:image_from_camera"} <= columns[
            f"/world/{cam}"
        ]
        assert "EncodedImage:blob" in columns[f"/world/{cam}/color"]
        assert "DepthImage:buffer" in columns[f"/world/{cam}/depth"]
        assert "Points2D:positions" in columns[f"/world/{cam}/estimate"]
    assert {"Points3D:positions", "Points3D:labels"} <= columns["/world/targets"]
