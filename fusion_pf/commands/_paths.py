"""Output-file checks shared by the commands that write files."""

from __future__ import annotations

from pathlib import Path

from fusion_pf.errors import InputError


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
        Files the command reads; writing over one of them is refused.

    Raises
    ------
    InputError
        When ``out`` is a directory, exists without ``force``, has no parent
        directory, or is one of ``inputs``.
    """
    if out.is_dir():
        raise InputError(f"{what} {out} is a directory; expected a file name")
    if out.exists() and not force:
        raise InputError(f"{what} {out} already exists; pass --force to overwrite it")
    if not out.parent.is_dir():
        raise InputError(f"{what} directory {out.parent} does not exist")
    for other in inputs:
        other = Path(other) if other is not None else None
        if other is not None and out.exists() and other.exists() and other.resolve() == out.resolve():
            raise InputError(f"{what} {out} is an input file; choose another output file")
