"""A sweep's plot drawn by a process of its own, forked before matplotlib is imported.

Why: drawing `sweep.png` needs matplotlib, whose import (about 0.8 s of CPU) was half of a
short sweep's fixed cost, paid after its points had run. `mgpusim sweep` forks a plotter once
it has imported its own modules (numpy, pandas and the model, which the plotter then shares
rather than imports again) and before it locks the folder (:func:`ahead`): the plotter
imports matplotlib while the sweep checks and runs its points, then draws the table the
sweep hands it (pickled through a pipe, length first) while the sweep writes the table. The
picture is drawn by the same code from the same table; only the process differs. Where no
plotter runs (the Python API, a system without `fork`, a process running other threads) or
the plotter failed, the sweep draws the plot itself, as before.

The plotter holds no lock and writes only the plot, into a temporary file of the folder that
the sweep moves into place (atomically, as it writes every file) once the table is written,
so a table that fails to be written leaves no new plot. It exits when it has drawn the table
it was handed; a sweep that ends without handing it one (an error, Ctrl-C) stops it at once,
and one killed leaves it to the end of its pipe (once the sweep's worker processes, which exit
with the sweep, are gone too).
"""
from __future__ import annotations

import contextlib
import os
import pickle
import signal
import struct
import sys
import threading
from pathlib import Path
from typing import Any, Iterator, Sequence

_HEADER = struct.Struct("!Q")
#: The plotter of this process's sweep command (None: the sweep draws its plot itself).
_ACTIVE: "Plotter | None" = None


class Plotter:
    """A forked process with the plotting module imported, waiting for one table to draw."""

    def __init__(self) -> None:
        request_r, request_w = os.pipe()
        reply_r, reply_w = os.pipe()
        pid = os.fork()
        if pid == 0:  # the plotter
            code = 1
            try:
                os.close(request_w)
                os.close(reply_r)
                code = _serve(request_r, reply_w)
            finally:
                os._exit(code)
        os.close(request_r)
        os.close(reply_w)
        self.pid, self._request, self._reply = pid, request_w, reply_r
        self._sent = self._closed = False
        self._answer: bool | None = None

    def submit(self, table: Any, keys: Sequence[str], path: Path, metric: str) -> bool:
        """Hand the plotter the table to draw into the file `path` (False: it is gone; draw
        it here). The sweep moves the file into place once the table is written."""
        if self._sent:
            return False
        self._sent = True
        data = pickle.dumps((table, list(keys), str(path), metric), protocol=pickle.HIGHEST_PROTOCOL)
        try:
            _write_all(self._request, _HEADER.pack(len(data)) + data)
        except OSError:
            return False
        return True

    def drawn(self) -> bool:
        """Wait for the plotter: whether it drew the plot it was handed (asked again, the
        same answer)."""
        if self._answer is None:
            self._answer = self._sent and not self._closed and _read_all(self._reply) == b"ok"
            self.close()
        return self._answer

    def close(self) -> None:
        """End the plotter: one handed a table is waited for; one handed none is stopped at
        once (it holds no lock and has written nothing), so that a command that fails early
        does not wait for its import of matplotlib."""
        if self._closed:
            return
        self._closed = True
        for fd in (self._request, self._reply):
            with contextlib.suppress(OSError):
                os.close(fd)
        if not self._sent:
            with contextlib.suppress(OSError):
                os.kill(self.pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(self.pid, 0)


def _serve(request: int, reply: int) -> int:
    """The plotter's life: import, wait for a table, draw it, say whether it did."""
    try:
        from mgpusim.io.plot import sweep_png  # noqa: PLC0415 - the import done ahead
    except BaseException:  # noqa: BLE001 - (Ctrl-C during the import too): the sweep draws it
        return 1
    try:
        head = _read_exactly(request, _HEADER.size)
        if head is None:
            return 0  # the sweep ended without a plot to draw
        data = _read_exactly(request, _HEADER.unpack(head)[0])
        if data is None:
            return 0
        table, keys, path, metric = pickle.loads(data)
        sweep_png(table, keys, Path(path), metric)
        _write_all(reply, b"ok")
        return 0
    except BaseException:  # noqa: BLE001 - the sweep draws it itself, and so reports what is wrong
        return 1


def _read_exactly(fd: int, n: int) -> bytes | None:
    """`n` bytes from `fd`, or None at the pipe's end before them."""
    parts, left = [], n
    while left:
        chunk = os.read(fd, min(left, 1 << 20))
        if not chunk:
            return None
        parts.append(chunk)
        left -= len(chunk)
    return b"".join(parts)


def _read_all(fd: int) -> bytes:
    parts = []
    while chunk := os.read(fd, 1 << 16):
        parts.append(chunk)
    return b"".join(parts)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


@contextlib.contextmanager
def ahead(enabled: bool = True) -> Iterator[None]:
    """A plotter for the sweep run inside (none where `enabled` is false, `fork` is missing or
    the process runs other threads)."""
    global _ACTIVE  # noqa: PLW0603 - one sweep command per process
    if not enabled or not hasattr(os, "fork") or _ACTIVE is not None or "matplotlib" in sys.modules \
            or threading.active_count() > 1:
        yield  # (matplotlib imported already: nothing to gain; other threads: a fork could
        return  # inherit a lock one of them holds, as where a test runner calls the command)
    _ACTIVE = Plotter()
    try:
        yield
    finally:
        _ACTIVE.close()
        _ACTIVE = None


def draw_ahead(table: Any, keys: Sequence[str], path: Path, metric: str) -> Plotter | None:
    """Hand `table` to this sweep command's plotter (None: there is none; draw it here)."""
    plotter = _ACTIVE
    if plotter is None or not plotter.submit(table, keys, path, metric):
        return None
    return plotter
