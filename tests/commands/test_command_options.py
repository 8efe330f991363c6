"""The commands' option configs: defaults when no flag is given, one-line errors naming the flag."""

from __future__ import annotations

import re

import pytest

from drivers.encoding import EncodingOptions
from fusion_pf.cli import _command_modules, build_parser, main
from fusion_pf.commands.import_ import ImportOptions
from fusion_pf.commands.record import RecordOptions
from fusion_pf.commands.score import ScoreOptions
from fusion_pf.commands.synth import SynthOptions
from fusion_pf.errors import InputError
from fusion_pf.experiments.paper import PAPER_PARTICLE_COUNTS
from fusion_pf.options import from_args

#: The shortest command line of each command with configs.
MINIMAL = {
    "annotate": ["annotate", "r.mcap", "--db", "d.sqlite"],
    "calibrate": ["calibrate", "r.mcap", "-o", "c.yaml"],
    "cues": ["cues", "r.mcap"],
    "demo": ["demo"],
    "import": ["import", "folder", "o.mcap"],
    "merge": ["merge", "a.mcap", "b.mcap", "--extrinsics", "c.yaml", "-o", "o.mcap"],
    "record": ["record", "synth", "o.mcap"],
    "render": ["render", "t.mcap"],
    "score": ["score", "t.csv", "--ground-truth", "g.mcap"],
    "synth": ["synth", "o.mcap"],
    "track": ["track", "r.mcap", "-o", "o.mcap"],
}
MODULES = {m.NAME: m for m in _command_modules()}


@pytest.mark.parametrize(
    "command, cls",
    [(name, cls) for name, argv in MINIMAL.items() for cls in MODULES[name].CONFIGS],
    ids=lambda x: x if isinstance(x, str) else x.__name__,
)
def test_flags_left_out_keep_the_config_defaults(command, cls):
    args = build_parser().parse_args(MINIMAL[command])
    assert from_args(cls, args) == cls()


def test_the_commands_with_configs_all_have_a_minimal_command_line():
    assert {name for name, m in MODULES.items() if m.CONFIGS} == set(MINIMAL)


def test_flags_reach_the_configs():
    args = build_parser().parse_args(
        ["synth", "o.mcap", "--frames", "7", "--size", "160x100", "--jpeg-quality", "50", "--color-format", "jpeg"]
    )
    assert from_args(SynthOptions, args) == SynthOptions(frames=7, size=(160, 100))
    assert from_args(EncodingOptions, args) == EncodingOptions(color_format="jpeg", jpeg_quality=50)
    args = build_parser().parse_args([*MINIMAL["score"], "--sweep"])
    assert from_args(ScoreOptions, args).sweep == PAPER_PARTICLE_COUNTS
    args = build_parser().parse_args([*MINIMAL["score"], "--sweep", "5,10", "--runs", "3"])
    assert from_args(ScoreOptions, args) == ScoreOptions(sweep=(5, 10), runs=3)


@pytest.mark.parametrize(
    "make, message",
    [
        (
            lambda: SynthOptions(frames=5, background_frames=6),
            "background_frames (--background-frames) must be in [0, frames 5], got 6",
        ),
        (
            lambda: SynthOptions(size=(16, 400)),
            "size (--size) must be WxH with both in [32, 4096], e.g. 640x400, got 16x400",
        ),
        (
            lambda: SynthOptions(depth_model="exact"),
            "depth_model (--depth-model) must be one of realistic, basic, got 'exact'",
        ),
        (
            lambda: EncodingOptions(jpeg_quality=101),
            "jpeg_quality (--jpeg-quality) must be an integer in [1, 100], got 101",
        ),
        (lambda: RecordOptions(fps=0.0), "fps (--fps) must be a number in [0.001, 1000], got 0"),
        (lambda: ImportOptions(cx=3.0), "--fy/--cx/--cy need --fx"),
        (lambda: ImportOptions(depth_unit="furlong"), "unknown depth unit 'furlong'"),
        (lambda: ImportOptions(hfov=0.5), "hfov (--hfov) must be a number in [1, 179], got 0.5"),
        (lambda: ScoreOptions(sweep=(5, 5)), "sweep (--sweep): particle counts must not repeat, got '5,5'"),
        (lambda: ScoreOptions(workers=2, scheduler="tcp://h:1"), "with --scheduler the cluster's own workers run"),
    ],
)
def test_bad_values_are_refused_by_the_config(make, message):
    with pytest.raises(InputError, match=re.escape(message)):
        make()


def test_bad_values_are_refused_before_any_file_is_written(tmp_path, capsys):
    out = tmp_path / "o.mcap"
    assert main(["synth", str(out), "--size", "640x"]) == 2
    assert (
        capsys.readouterr().err.strip() == "fusion-pf: error: --size: expected WxH in pixels, e.g. 640x400, got '640x'"
    )
    assert main(["record", "synth:frames=2", str(out), "--compression", "bzip2"]) == 2
    assert capsys.readouterr().err.strip() == (
        "fusion-pf: error: compression (--compression) must be one of zstd, lz4, none, got 'bzip2'"
    )
    assert main(["import", str(tmp_path), str(out), "--fps", "0"]) == 2
    assert "fps (--fps) must be a number in [0.001, 1000], got 0" in capsys.readouterr().err
    assert not out.exists()
