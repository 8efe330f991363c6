"""Exception types of fusion-pf.

Every error a user can cause (a bad file, a bad option, a missing device) is a
:class:`FusionPFError`. The command line prints its message on one line and exits
non-zero without a traceback; library callers catch it like any ``ValueError``.
"""

from __future__ import annotations


class FusionPFError(Exception):
    """Base class of every error fusion-pf raises on purpose.

    Attributes
    ----------
    exit_code : int
        Process exit status the command line uses for this error.
    """

    exit_code = 2


class InputError(FusionPFError, ValueError):
    """A value given by the user or read from a file is not what was expected.

    The message names the bad value and what was expected, e.g.
    ``"depth must be uint16 millimetres, got float32"``.
    """


class RecordingError(FusionPFError):
    """A recording cannot be read or does not follow docs/recording-format.md."""


class DeviceError(FusionPFError):
    """A camera is missing, was unplugged, or timed out."""


#: Exit status of a command that finished but could not use every input frame (a damaged or
#: truncated recording): it printed what it skipped and why (``SourceStats.loss_summary()``).
#: 0 = everything used, 2 = refused (a FusionPFError), 3 = partial, 130/143/129 = stopped by
#: Ctrl-C/SIGTERM/SIGHUP, 141 = output pipe closed.
PARTIAL_EXIT_CODE = 3
