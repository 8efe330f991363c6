"""``fusion-pf track --rerun`` of one camera: what a real Rerun server (``rerun --save``, the rerun-sdk wheel's
viewer binary) received, read back with ``rerun rrd print -vvv``: every target's ``2 sigma_px`` disc."""

import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.tracker_topics import read_json_topic

from ..conftest import CLI, rerun_process
from .test_live import live_serve


def _rows(printed: str, entity: str) -> dict[int, list[str]]:
    """The data rows of ``entity``'s chunks in ``rerun rrd print -vvv`` output: per ``frame`` index its cells."""
    out: dict[int, list[str]] = {}
    inside = False
    for line in printed.splitlines():
        if line.startswith("Chunk("):
            inside = line.rstrip().endswith(f"- {entity} -")
        elif inside and "row_" in line and "┆" in line:
            cells = [c.strip(" │") for c in line.split("┆")]
            out[int(cells[2])] = cells
    return out


def test_every_target_s_uncertainty_reaches_rerun_as_a_two_sigma_disc(tmp_path):
    scene = tmp_path / "two.mcap"
    synth = [*CLI, "synth", scene, "--hands", "2", "--frames", "30", "--size", "160x100", "--background-frames", "5"]
    assert subprocess.run([str(c) for c in synth], capture_output=True).returncode == 0
    port = live_serve.free_port()
    saved, out = tmp_path / "live.rrd", tmp_path / "o.mcap"
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    with rerun_process("--port", port, "--save", saved):
        for _ in range(100):  # the server starts listening
            argv = [*CLI, "track", scene, "-o", out, "--targets", "right_hand,left_hand", "--rerun", url]
            r = subprocess.run(
                [str(c) for c in [*argv, "--no-progress", "--live-queue", "100"]], capture_output=True, text=True
            )
            if "no Rerun viewer answers" not in r.stderr:
                break
            time.sleep(0.2)
        assert r.returncode == 0, r.stderr
        assert "30 frames published, 0 dropped" in r.stderr
        time.sleep(1.0)
    rerun = Path(sys.executable).with_name("rerun")
    printed = subprocess.run([rerun, "rrd", "print", "-vvv", saved], capture_output=True, text=True, timeout=60)
    assert printed.returncode == 0, printed.stderr
    discs = _rows(printed.stdout, "/camera/uncertainty")
    estimates = {m["frame"]: m["targets"] for _, m in read_json_topic(out, "/tracker/estimate")}
    with_sigma = {f: t for f, t in estimates.items() if any(x["sigma_px"] is not None for x in t.values())}
    assert len(with_sigma) >= 20 and set(with_sigma) <= set(discs)
    for frame, targets in with_sigma.items():
        radii = [float(x) for x in discs[frame][-1].strip("[]").split(",")]
        want = [2.0 * x["sigma_px"] for x in targets.values() if x["sigma_px"] is not None]
        assert sorted(radii) == pytest.approx(sorted(want), rel=1e-5), frame
        assert discs[frame][-3] == "[-5.0]"  # under the estimate's own point, over the image
