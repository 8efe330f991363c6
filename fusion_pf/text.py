"""Text from files made safe for a terminal."""

from __future__ import annotations


def printable(text: object) -> str:
    """``str(text)`` with every non-printable character escaped (``"\\x1b]0;x\\x07"`` -> ``"\\\\x1b]0;x\\\\x07"``).

    Strings read from a recording (writer, metadata, topic and schema names)
    reach the terminal through ``info`` and error messages; escaping control
    and format characters (ESC, BEL, CR, bidirectional overrides, ...) keeps a
    crafted file from setting the terminal title, moving the cursor or
    printing fake coloured text. Printable non-ASCII text is kept as it is.
    """
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in str(text))
