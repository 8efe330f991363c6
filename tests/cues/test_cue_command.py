import json
import math

import cv2
import pytest

from fusion_pf.cli import main


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "synth.mcap"
    assert main(["record", "synth:frames=9,background_frames=4,seed=0,size=320x200", str(path)]) == 0
    return path


def test_cues_command_writes_one_labelled_sheet_per_cue(recording, tmp_path, capsys):
    capsys.readouterr()
    assert main(["cues", str(recording), "--frame", "6", "--stages", str(tmp_path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["frame"] == 6 and doc["background"].startswith("4 empty-scene frames")
    assert set(doc["cues"]) == {"colour", "depth", "hand", "skin_rg", "skin_rgb", "skeleton"}
    colour = doc["cues"]["colour"]
    assert colour["error_px"] < 14.0 and 0 < colour["quality"] <= 1  # bare-forearm bias: 9.7 px measured
    assert all(math.isfinite(r["latency_ms"]) and r["latency_ms"] >= 0 for r in doc["cues"].values())
    sheets = sorted(p.name for p in tmp_path.iterdir())
    assert sheets == [f"frame000006_{n}.png" for n in ("colour", "depth", "skin_rg", "skin_rgb")]
    colour_sheet = cv2.imread(str(tmp_path / "frame000006_colour.png"))
    depth_sheet = cv2.imread(str(tmp_path / "frame000006_depth.png"))
    assert colour_sheet.shape[1] == 4 * 200 and colour_sheet.shape[0] == 22 + 3 * (200 + 22)  # 10 tiles, 4 a row
    assert depth_sheet.shape[0] == 22 + 3 * (200 + 22)  # 11 tiles


def test_cues_stages_folder_is_created(recording, tmp_path, capsys):
    """Issue 14 item 9: like the other commands, --stages creates its folder."""
    out = tmp_path / "new" / "stages"
    assert main(["cues", str(recording), "--frame", "6", "--stages", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        f"frame000006_{n}.png" for n in ("colour", "depth", "skin_rg", "skin_rgb")
    ]


def test_cues_command_text_output_and_full_frame(recording, capsys):
    capsys.readouterr()
    assert main(["cues", str(recording), "--prior", "full", "--background-k", "3"]) == 0
    out = capsys.readouterr().out
    assert "frame 4 of" in out and "roi full frame" in out
    assert out.count("\n") == 2 + 6


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["--frame", "99"], "--frame must be in [0, 8], got 99"),
        (
            ["--colour-lower", "50", "--colour-upper", "10"],
            "colour_upper (--colour-upper) must be >= colour_lower 50, got 10",
        ),
        (["--depth-range-mm", "9"], "--depth-range-mm: expected 2 comma-separated numbers, got '9'"),
        (["--cues", "colour,sonar"], "cues must be distinct names among"),
        (["--stages", __file__], "is a file; expected a directory"),
    ],
)
def test_cues_command_bad_options_exit_2_with_one_line(recording, capsys, argv, needle):
    capsys.readouterr()
    assert main(["cues", str(recording), *argv]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1


def test_cues_command_with_empty_scene_file_and_skin_model(recording, tmp_path, scene, capsys):
    from fusion_pf.cues import LabGmmSkin

    empty = tmp_path / "empty.mcap"
    assert main(["record", "synth:frames=3,background_frames=3,seed=0,size=320x200", str(empty)]) == 0
    s = scene()
    model = tmp_path / "skin.npz"
    LabGmmSkin.fit(s["color"].reshape(-1, 3), s["hand"].ravel(), rng=0).save(model)
    capsys.readouterr()
    assert (
        main(
            [
                "cues",
                str(recording),
                "--frame",
                "5",
                "--background",
                str(empty),
                "--skin-model",
                str(model),
                "--prior",
                "truth",
                "--json",
            ]
        )
        == 0
    )
    doc = json.loads(capsys.readouterr().out)
    assert doc["background"] == f"{empty}"
    assert "skin_lab" in doc["cues"]
    assert doc["cues"]["colour"]["error_px"] < 14.0  # 9.4 px measured
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a model")
    assert main(["cues", str(recording), "--skin-model", str(bad)]) == 2
    assert "LabGmmSkin" in capsys.readouterr().err
