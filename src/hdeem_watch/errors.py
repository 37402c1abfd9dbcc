"""The one exception type for bad user input.

Anything the user can get wrong (a file, a field, a value, a command-line flag) raises
:class:`InputError` with a one-line message naming what was wrong and what was expected. The
command line prints it on stderr as ``hdeem-watch: error: <message>`` and exits with code 2; every
other exception is a bug or an environment failure (exit code 1).

Example:
    >>> raise InputError("memspec.json: mempowerspec.idd0 = 58.5 looks like mA; expected amperes (0.0585)")
    Traceback (most recent call last):
    ...
    hdeem_watch.errors.InputError: memspec.json: mempowerspec.idd0 = 58.5 looks like mA; expected amperes (0.0585)
"""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input from the user: a file, field or value that is not what was expected."""


#: Characters of an excerpt shown in a message before it is cut with "...".
EXCERPT_CHARS = 40

_SHOWN_AS = {0x09: "\\t", 0x0A: "\\n", 0x0D: "\\r", 0x27: "\\'", 0x5C: "\\\\"}


def excerpt(text: bytes | str, limit: int = EXCERPT_CHARS) -> str:
    """``text`` quoted for a one-line message, safe on any terminal.

    Printable ASCII is shown as is, every other byte (control characters, carriage returns,
    escape sequences, binary, non-ASCII UTF-8) as a Python escape; the quoted body is cut after
    ``limit`` characters (with ``...``), so a binary file named as a text file gives a short line.

    Example:
        >>> print(excerpt(b"0x12\\r34 R"))
        '0x12\\r34 R'
        >>> print(excerpt(b"\\x7fELF\\x02\\x01\\x01" + bytes(100), limit=20))
        '\\x7fELF\\x02\\x01\\x01'...
    """
    data = text.encode("utf-8", "backslashreplace") if isinstance(text, str) else bytes(text)
    shown: list[str] = []
    length = 0
    for byte in data:
        piece = _SHOWN_AS.get(byte) or (chr(byte) if 0x20 <= byte < 0x7F else f"\\x{byte:02x}")
        if length + len(piece) > limit:
            return "'" + "".join(shown) + "'..."
        shown.append(piece)
        length += len(piece)
    return "'" + "".join(shown) + "'"


def not_a_file_error(path: str | Path, what: str) -> InputError:
    """The error for a ``path`` that should name an existing ``what`` (e.g. "trace file") but does
    not: it says whether it is a directory, something other than a file, or missing.

    Example:
        >>> print(not_a_file_error("/", "trace file"))
        /: is a directory; expected a trace file
    """
    where = Path(path)
    if where.is_dir():
        return InputError(f"{path}: is a directory; expected a {what}")
    if where.exists():
        return InputError(f"{path}: not a regular file; expected a {what}")
    return InputError(f"{path}: no such {what}")
