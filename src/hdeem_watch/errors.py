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


class InputError(ValueError):
    """Bad input from the user: a file, field or value that is not what was expected."""
