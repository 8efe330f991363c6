"""The console script: help texts, one-line errors, exit codes (run as a real subprocess)."""

import pytest

from fusion_pf.cli import build_parser


def test_help_lists_every_subcommand(fusion_pf):
    p = fusion_pf("--help")
    assert p.returncode == 0
    sub = build_parser()._subparsers._group_actions[0].choices
    for name in sub:
        assert name in p.stdout
    assert {"info", "record", "synth", "track", "score", "demo", "annotate", "cues"} <= set(sub)


@pytest.mark.parametrize("name", sorted(build_parser()._subparsers._group_actions[0].choices))
def test_every_subcommand_has_help(name, fusion_pf):
    p = fusion_pf(name, "--help")
    assert p.returncode == 0, p.stderr
    assert "usage: fusion-pf " + name in p.stdout


def test_unknown_source_is_one_line_exit_2(tmp_path, fusion_pf):
    p = fusion_pf("record", "webcam:0", str(tmp_path / "x.mcap"))
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0, p.stderr
    assert "unknown source 'webcam:0'" in p.stderr
    assert "Traceback" not in p.stderr
