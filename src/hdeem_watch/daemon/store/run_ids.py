"""The run ids a daemon gave out before their rows were on disk: a durable high-water mark.

Run ids are ``r<n>``, unique per node: a restarted daemon continues after the highest stored one.
A run acknowledged while the state database cannot be written (a full disk) lives in memory until
its write goes through; a ``kill -9`` meanwhile loses the row, and the next daemon would give its
id again to another run. So whenever a run id is given out without its row on disk, its number is
written to :class:`RunIdMark`'s file beside the database: a file of fixed size, allocated when the
store opens and overwritten in place (an overwrite of allocated blocks needs no free space), then
synced. The next start continues after the larger of the highest stored id and the mark. Only a
file system that refuses every write (mounted read-only) can lose the mark: the replies say
``"stored": false`` then.

Example:
    >>> import tempfile, pathlib
    >>> mark = RunIdMark(pathlib.Path(tempfile.mkdtemp()) / "state.db.run-ids")
    >>> mark.read(), mark.write(8), mark.read()
    (0, True, 8)
    >>> mark.close()
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

log = logging.getLogger("hdeem_watch.daemon.store.database")

#: Size of the mark's file (one block, allocated at open).
FILE_BYTES = 4096
#: Bytes of the mark itself at the start of the file: the number, a newline, spaces.
MARK_BYTES = 32


class RunIdMark:
    """The highest run number given out without its row on disk (0: none).

    Args:
        path: the mark's file (created mode 0600 and allocated when missing).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd: int | None = None
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        except OSError as error:
            log.warning("%s: cannot open the run id mark (%s); run ids given while the database cannot be "
                        "written may be given again after a crash", path, error.strerror)
            return
        self._fd = fd
        try:
            if os.fstat(fd).st_size < FILE_BYTES:
                os.pwrite(fd, self._encode(self.read()) + bytes(FILE_BYTES - MARK_BYTES), 0)
                os.fsync(fd)
        except OSError as error:
            log.warning("%s: cannot allocate the run id mark (%s)", path, error.strerror)

    @staticmethod
    def _encode(seq: int) -> bytes:
        return f"{int(seq)}\n".encode().ljust(MARK_BYTES)

    def read(self) -> int:
        """The mark (0 when none, or unreadable)."""
        if self._fd is None:
            return 0
        try:
            text = os.pread(self._fd, MARK_BYTES, 0).split(b"\n", 1)[0].strip()
            return int(text) if text.isdigit() else 0
        except (OSError, ValueError):
            return 0

    def write(self, seq: int) -> bool:
        """Record ``seq`` durably (in place, synced); False when the file system refused."""
        if self._fd is None:
            return False
        try:
            os.pwrite(self._fd, self._encode(seq), 0)
            os.fsync(self._fd)
        except OSError as error:
            log.warning("%s: run id mark r%d not written (%s)", self.path, seq, error.strerror)
            return False
        return True

    def refusal(self) -> str | None:
        """Why the file system refuses a write now (None when it takes one): the mark rewritten
        as it is, unsynced (a page-cache write; an ext4 that remounted itself read-only after an
        error refuses it although ``statvfs`` may not say read-only)."""
        if self._fd is None:
            return None
        try:
            os.pwrite(self._fd, os.pread(self._fd, MARK_BYTES, 0), 0)
        except OSError as error:
            return error.strerror or str(error)
        return None

    def close(self) -> None:
        """Close the file."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
