"""Output-file checks shared by the commands that write files.

A file is the same as another when the two names reach one file, by any route:
the same path, a symbolic link, a hard link, a bind mount. Files are compared by
what ``os.stat`` says (device and inode, :func:`os.path.samefile`), never by
their resolved paths, which differ for a hard link or a bind mount. An output that
does not exist yet cannot be an input. Every check runs before anything is
opened for writing.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from fusion_pf.errors import InputError

#: Files next to an SQLite database that belong to it.
SQLITE_SIDECARS = ("-wal", "-shm", "-journal")


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` are one existing file (same device and inode), whatever the names."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def _files_in(folder: Path) -> Iterable[Path]:
    for root, _dirs, names in os.walk(folder):
        for name in names:
            yield Path(root) / name


def input_holding(out: Path, inputs: Iterable[str | os.PathLike | None]) -> Path | None:
    """The input that ``out`` is (or, for a folder input, a file of that folder), or None.

    ``inputs`` may hold None and names that are not files (``synth:...``); a
    folder input (an image folder, a ROS 2 bag) stands for every file in it.
    """
    if not os.path.lexists(out):
        return None
    for name in inputs:
        if name is None:
            continue
        other = Path(name)
        if same_file(out, other):
            return other
        if other.is_dir() and not out.is_dir():
            for f in _files_in(other):
                if same_file(out, f):
                    return f
    return None


def check_not_input(out: Path, inputs: Iterable[str | os.PathLike | None], what: str = "output") -> None:
    """Refuse ``out`` when it is one of ``inputs`` by any route (link, mount, same path); --force or not."""
    found = input_holding(out, inputs)
    if found is not None:
        how = "" if str(found) == str(out) else f" ({found}, by another name: a link or a mount)"
        raise InputError(f"{what} {out} is an input file{how}; choose another output file (--force or not)")


def check_output(out: Path, *, force: bool, what: str = "output", inputs: tuple = ()) -> None:
    """Refuse an output path that cannot or must not be written.

    Parameters
    ----------
    out : Path
        File the command will write.
    force : bool
        Whether an existing file may be overwritten.
    what : str
        How the message names the file (``"output"``, ``"--csv"``).
    inputs : tuple of str or Path
        Files the command reads; writing over one of them is refused, with or
        without ``force`` (:func:`check_not_input`).

    Raises
    ------
    InputError
        When ``out`` is a directory, exists without ``force``, has no parent
        directory, or is one of ``inputs``.
    """
    if out.is_dir():
        raise InputError(f"{what} {out} is a directory; expected a file name")
    check_not_input(out, inputs, what)
    if out.exists() and not force:
        raise InputError(f"{what} {out} already exists; pass --force to overwrite it")
    if not out.parent.is_dir():
        raise InputError(f"{what} directory {out.parent} does not exist")


def _same_target(a: Path, b: Path) -> bool:
    """Whether writing ``a`` and writing ``b`` would write one file (existing or not)."""
    if same_file(a, b):
        return True
    if os.path.lexists(a) or os.path.lexists(b):
        return a.resolve() == b.resolve()
    return a.name == b.name and (same_file(a.parent, b.parent) or a.parent.resolve() == b.parent.resolve())


def check_distinct(outputs: Iterable[tuple[str, Path | None]]) -> None:
    """Refuse two outputs of one command that are one file (by any route); None entries are skipped."""
    seen: list[tuple[str, Path]] = []
    for what, out in outputs:
        if out is None:
            continue
        for other_what, other in seen:
            if _same_target(out, other):
                raise InputError(f"{what} {out} and {other_what} {other} are the same file; choose two files")
        seen.append((what, out))


def check_folder_outputs(
    folder: Path, names: Iterable[str], inputs: Iterable[str | os.PathLike | None], what: str
) -> None:
    """Refuse a folder output when a file the command writes in it (``names``, globs allowed) is an input."""
    if not folder.is_dir():
        return
    inputs = tuple(inputs)
    for name in names:
        for out in sorted(folder.glob(name)) if any(c in name for c in "*?[") else [folder / name]:
            check_not_input(out, inputs, f"{what} file")
