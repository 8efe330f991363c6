"""The layout's rules: one-way imports, light core imports, one definition per default."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

import fusion_pf
from fusion_pf.cli import _command_modules, build_parser
from fusion_pf.commands.cues import WINDOW_OPTIONS
from fusion_pf.commands.demo import TRACK_OPTIONS
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


def test_one_tracking_pipeline_for_one_target_or_several():
    """``track`` and ``track --targets`` run the same ``pipeline.track``; no second pipeline module exists."""
    import importlib.util

    assert importlib.util.find_spec("fusion_pf.pipeline.targets") is None
    source = (PACKAGE / "commands" / "track.py").read_text()
    tree = ast.parse(source)
    pipeline_names = {
        a.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("fusion_pf.pipeline")
        for a in node.names
    }
    assert "track" in pipeline_names and not any(n.startswith("track_") for n in pipeline_names)
    calls = [
        n.func.id
        for n in ast.walk(tree)
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "track"
    ]
    assert len(calls) == 2  # the single palm and the several targets' outputs, both from pipeline.track


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


#: The command modules by command name.
COMMANDS = {m.NAME: m for m in _command_modules()}
#: (command, config class) -> the only fields it registers, where a command takes part of a config.
PARTIAL = {("cues", TrackConfig): WINDOW_OPTIONS, ("demo", TrackConfig): TRACK_OPTIONS}
#: Options with a plain argparse default that is not an option of a stage: output places and encodings.
PLAIN_DEFAULTS = {("demo", "out"), ("track", "color_format"), ("cues", "prior")}


def _shown(spec, default) -> str:
    """The default as ``--help`` should show it, computed here independently of options.option_help."""
    if spec.show:
        return spec.show(default)
    if default is None:
        return "none"
    if isinstance(default, bool):
        return "on" if default else "off"
    return f"{default:g}" if isinstance(default, float) else str(default)


@pytest.mark.parametrize(
    "command, cls",
    [(name, cls) for name, module in COMMANDS.items() for cls in module.CONFIGS],
    ids=lambda x: x if isinstance(x, str) else x.__name__,
)
def test_help_shows_the_real_defaults(command, cls):
    helps = _help_of(command)
    only = PARTIAL.get((command, cls))
    fields = [
        f
        for f in dataclasses.fields(cls)
        if "spec" in f.metadata and f.metadata["spec"].cli and (only is None or f.name in only)
    ]
    assert fields
    for f in fields:
        assert helps.get(f.name) == option_help(f), (command, f.name)
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        assert f"[default: {_shown(f.metadata['spec'], default)}]" in helps[f.name], (f.name, helps[f.name])


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_default_comes_from_a_config(command):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    registered = {
        f.name
        for cls in COMMANDS[command].CONFIGS
        for f in dataclasses.fields(cls)
        if f.name in PARTIAL.get((command, cls), (f.name,))
    }
    plain = {a.dest for a in sub._actions if a.option_strings and a.default not in (None, False, [], argparse.SUPPRESS)}
    assert plain - {d for c, d in PLAIN_DEFAULTS if c == command} == set()
    # a config's flag keeps its default in the config (argparse sees SUPPRESS)
    assert all(a.default is argparse.SUPPRESS for a in sub._actions if a.dest in registered and a.option_strings)


def test_the_commands_with_options_have_configs():
    with_configs = {name for name, module in COMMANDS.items() if module.CONFIGS}
    assert with_configs == {
        "annotate",
        "calibrate",
        "cues",
        "demo",
        "import",
        "merge",
        "record",
        "render",
        "score",
        "synth",
        "track",
    }
    assert COMMANDS["info"].CONFIGS == COMMANDS["annotations"].CONFIGS == ()


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
