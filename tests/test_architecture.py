"""The layout's rules: one-way imports, light core imports, one definition per default."""

from __future__ import annotations

import ast
import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

import fusion_pf
from fusion_pf.cli import build_parser
from fusion_pf.cues.registry import CueOptions
from fusion_pf.filter import KalmanFilter, ParticleFilter
from fusion_pf.options import from_args, option_help
from fusion_pf.pipeline import TrackConfig

PACKAGE = Path(fusion_pf.__file__).resolve().parent


def _imports(path: Path) -> set[str]:
    """Top-level module names imported anywhere in ``path`` (function-local imports included)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_only_the_command_line_layer_imports_drivers():
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] == "commands" or rel.name == "cli.py":
            continue
        if "drivers" in _imports(path):
            offenders.append(str(rel))
    assert offenders == []
    # the check itself sees an import of drivers where there is one
    assert "drivers" in _imports(PACKAGE / "commands" / "track.py")


@pytest.mark.parametrize(
    "module, banned",
    [
        ("fusion_pf.filter", ("cv2", "drivers", "matplotlib", "flask")),
        ("fusion_pf.score", ("cv2", "drivers", "matplotlib", "flask", "mcap")),
        ("fusion_pf.options", ("cv2", "drivers")),
        ("fusion_pf.pipeline", ("drivers", "matplotlib", "flask", "mcap")),
    ],
)
def test_core_imports_stay_light(module, banned):
    code = f"import sys, {module}; print(','.join(m for m in {banned!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == ""


def _help_of(command: str) -> dict[str, str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    return {a.dest: a.help for a in sub._actions}


@pytest.mark.parametrize("command", ["track", "cues"])
def test_help_shows_the_real_defaults(command):
    from fusion_pf.commands.cues import WINDOW_OPTIONS

    helps = _help_of(command)
    seen = 0
    for cls in (TrackConfig, CueOptions):
        for f in dataclasses.fields(cls):
            own = command == "cues" and cls is TrackConfig and f.name not in WINDOW_OPTIONS
            if f.name in helps and not own:
                assert helps[f.name] == option_help(f)
                default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
                spec = f.metadata["spec"]
                shown = (
                    spec.show(default)
                    if spec.show
                    else (
                        "none"
                        if default is None
                        else ("on" if default else "off")
                        if isinstance(default, bool)
                        else f"{default:g}"
                        if isinstance(default, float)
                        else str(default)
                    )
                )
                assert f"[default: {shown}]" in helps[f.name], (f.name, helps[f.name])
                seen += 1
    assert seen >= (10 if command == "track" else 8)


def test_flags_left_out_keep_the_config_defaults():
    parser = build_parser()
    args = parser.parse_args(["track", "x.mcap", "-o", "y.mcap"])
    assert from_args(TrackConfig, args, cue_options=from_args(CueOptions, args)) == TrackConfig()
    args = parser.parse_args(["track", "x.mcap", "-o", "y.mcap", "--particles", "7", "--colour-lower", "20"])
    config = from_args(TrackConfig, args, cue_options=from_args(CueOptions, args))
    assert config.particles == 7 and config.cue_options.colour_lower == 20


def test_filters_and_pipeline_share_one_definition_of_each_noise_default():
    config = TrackConfig()
    pf, kf = ParticleFilter(), KalmanFilter()
    assert pf.noise_px == kf.noise_px == dict(config.noise_px)
    assert pf.process_noise == config.process_noise
