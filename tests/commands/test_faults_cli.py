"""Issue 14 items 4, 5, 8 and 9 at the command line: stop signals, full disk, hostile strings, pipes, setup."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from drivers import mcap_format as fmt
from drivers.mcap_replay import MAGIC, McapReplay
from fusion_pf.frame import Intrinsics

REPO = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "fusion_pf"]
ENDLESS = "synth:frames=100000,size=160x100"


def start_record(out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [*CLI, "record", ENDLESS, str(out), *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def wait_for_frames(out: Path, min_bytes: int = 400_000, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if out.exists() and out.stat().st_size >= min_bytes:
            return
        time.sleep(0.05)
    raise AssertionError(f"{out} did not grow to {min_bytes} bytes")


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129), (signal.SIGINT, 130)])
def test_stop_signals_finalise_the_file_and_print_the_summary(tmp_path, sig, code):
    out = tmp_path / "stop.mcap"
    proc = start_record(out)
    wait_for_frames(out)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr
    with McapReplay(out) as replay:
        info = replay.info()
        n = len(replay)
    assert info.indexed and not info.truncated  # finalised: summary and footer written
    assert stdout.startswith(f"recorded {n} frames (") and f"{out.stat().st_size} bytes" in stdout
    assert n > 0


def test_header_reaches_the_disk_before_the_first_chunk(tmp_path):
    """Killed (SIGKILL) before any chunk: the file starts like an MCAP file instead of being empty."""
    out = tmp_path / "early.mcap"
    proc = subprocess.Popen(
        [*CLI, "record", "synth:frames=100000,size=1280x720", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    while not (out.exists() and out.stat().st_size > 0) and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.kill()
    proc.wait(timeout=120)
    data = out.read_bytes()
    assert data.startswith(MAGIC) and len(data) > 100
    with pytest.raises(Exception) as err:  # no chunk yet, so no frame; the reader says why in one line
        McapReplay(out).open()
    assert "no /camera" in str(err.value) and "\n" not in str(err.value)


def test_ctrl_c_while_the_commands_import_is_quiet(monkeypatch, capsys):
    """A Ctrl-C in the first ~0.1 s (while numpy and the commands import) exits 130 without a traceback."""
    from fusion_pf import cli

    real = cli.build_parser

    def interrupted_build():
        os.kill(os.getpid(), signal.SIGINT)  # as if Ctrl-C arrived during the imports
        return real()

    monkeypatch.setattr(cli, "build_parser", interrupted_build)
    assert cli.main(["info", "/nonexistent/none.mcap"]) == 130  # stopped before the command ran
    assert capsys.readouterr().err.strip() == "fusion-pf: interrupted"


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MiB tmpfs (needs root, as the test run has)."""
    where = tmp_path / "disk"
    where.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(where)], capture_output=True)
    assert mounted.returncode == 0, f"cannot mount a small tmpfs: {mounted.stderr.decode().strip()}"
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def test_full_disk_summary_tells_the_truth(small_disk):
    out = small_disk / "full.mcap"
    proc = subprocess.run(
        [*CLI, "record", "synth:frames=60,size=320x200", str(out)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("fusion-pf: error:")]
    assert len(errors) == 1 and "No space left on device" in errors[0]
    with McapReplay(out) as replay:
        in_file = sum(1 for _ in replay)
    size = out.stat().st_size
    assert 0 < in_file < 60
    assert proc.stdout.startswith(f"recorded {in_file} frames (") and "could not be written" in proc.stdout
    assert f"; {size} bytes" in proc.stdout


def test_info_escapes_terminal_control_characters(tmp_path):
    """A crafted file cannot set the terminal title or print fake coloured text through ``info``."""
    evil = "\x1b]0;pwned\x07\x1b[2J\x1b[32mverified OK\x1b[0m\r\u202e"
    path = tmp_path / "evil.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="writer" + evil)
        w.add_metadata(fmt.RECORDING_METADATA, {"note" + evil: "value" + evil})
        cal = w.register_channel(
            fmt.CALIBRATION_TOPIC, "protobuf", w.register_schema(fmt.CAMERA_CALIBRATION, "protobuf", b"")
        )
        col = w.register_channel(fmt.COLOR_TOPIC, "protobuf", w.register_schema(fmt.RAW_IMAGE + evil, "protobuf", b""))
        extra = w.register_channel(
            "/x" + evil, "json" + evil, w.register_schema("s" + evil, "jsonschema" + evil, b"{}")
        )
        w.add_message(cal, 0, fmt.encode_calibration(Intrinsics(64, 48, 50, 50, 32, 24), 0).SerializeToString(), 0)
        w.add_message(col, 0, fmt.encode_color(np.zeros((48, 64, 3), np.uint8), 0).SerializeToString(), 0)
        w.add_message(extra, 0, b"{}", 0)
        w.finish()
    proc = subprocess.run([*CLI, "info", str(path)], capture_output=True, text=True, timeout=300)
    shown = proc.stdout + proc.stderr
    for bad in ("\x1b", "\x07", "\r", "\u202e"):
        assert bad not in shown
    assert "\\x1b]0;pwned\\x07" in shown and "\\u202e" in shown


def test_info_into_a_closed_pipe_exits_quietly(tmp_path):
    path = tmp_path / "r.mcap"
    assert (
        subprocess.run(
            [*CLI, "record", "synth:frames=3,size=160x100", str(path)], capture_output=True, timeout=120
        ).returncode
        == 0
    )
    proc = subprocess.run(
        f"{' '.join(map(str, CLI))} info {path} | head -1; echo ${{PIPESTATUS[0]}}",
        shell=True,
        executable="/bin/bash",
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("file ") and lines[-1] in ("0", "141")  # 141: the pipe closed before the end
    assert proc.stderr == ""


def test_setup_installs_python3_venv_when_python_cannot_make_a_venv(tmp_path):
    """tools/setup.sh on a stock Debian (python3 without ensurepip) asks apt for python3-venv first."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    log = tmp_path / "apt.log"
    real = shutil.which("python3")
    (bin_dir / "python3").write_text(  # the stock Debian python3: venv without ensurepip
        f'#!/bin/sh\ncase "$*" in *ensurepip*|*"-m venv"*) exit 1;; esac\nexec {real} "$@"\n'
    )
    (bin_dir / "apt-get").write_text(f'#!/bin/sh\necho "$@" >> {log}\n')
    (bin_dir / "dpkg").write_text("#!/bin/sh\nexit 0\n")
    for tool in bin_dir.iterdir():
        tool.chmod(0o755)
    repo = tmp_path / "repo"
    (repo / "tools").mkdir(parents=True)
    shutil.copy(REPO / "tools" / "setup.sh", repo / "tools" / "setup.sh")
    proc = subprocess.run(
        ["bash", str(repo / "tools" / "setup.sh")],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "PYTHON": "python3"},
    )
    assert proc.returncode != 0  # the fake python3 cannot make the venv; apt was asked first
    installs = [line.split() for line in log.read_text().splitlines() if line.startswith("install")]
    version = "{}.{}".format(*sys.version_info[:2])
    assert installs and "python3-venv" in installs[0] and f"python{version}-venv" in installs[0]


@pytest.mark.slow
def test_build_has_no_licence_warnings(tmp_path):
    """pyproject's SPDX ``license = "MIT"`` builds without setuptools' licence deprecation warnings."""
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(REPO), "--no-deps", "-v", "-w", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = (proc.stdout + proc.stderr).lower()
    assert "deprecat" not in out and "project.license" not in out  # the warnings, not the shipped LICENSE files
    assert list(tmp_path.glob("fusion_pf-*.whl"))


def test_constraints_pin_every_declared_dependency():
    """tools/constraints.txt pins each requirement of pyproject (package, oak, dev) to a version its specifier allows."""
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11, the version the pins are for
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    pins = {}
    for line in (REPO / "tools" / "constraints.txt").read_text().splitlines():
        name, sep, version = line.partition("==")
        assert sep and version, f"not a pin: {line!r}"
        pins[canonicalize_name(name)] = version
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    declared = [
        *project["dependencies"],
        *project["optional-dependencies"]["oak"],
        *project["optional-dependencies"]["dev"],
    ]
    for spec in declared:
        req = Requirement(spec)
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is not pinned in tools/constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), f"{req.name}=={pins[name]} outside {req.specifier}"
