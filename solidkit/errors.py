"""Exceptions raised by solidkit; the CLI turns them into one-line messages. :func:`library_output` keeps what C
libraries print on stderr out of the terminal, for that one line."""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterator
from typing import Any


class SolidkitError(Exception):
    """Base class: an error a user can act on (bad input, missing metadata, ...)."""


class InputError(SolidkitError):
    """A file is missing, unreadable, corrupt or of the wrong kind."""


class PanoramaError(InputError):
    """An image is not a valid equirectangular panorama (W != 2H, NaN/Inf, wrong channels)."""


class ConventionsError(SolidkitError):
    """A file or checkpoint was written under another conventions version."""


class InputWarning(UserWarning):
    """A problem of an input that did not stop the command (e.g. corrupt JPEG data decoded anyway); the CLI
    prints it as one ``warning:`` line naming the file."""


class LibraryOutput:
    """What C libraries wrote on stderr inside :func:`library_output` (``text``: so far, while the block runs)."""

    def __init__(self) -> None:
        self._text = ""
        self._live: tuple[int, int] | None = None  # (fd, offset) of the redirection while the block runs

    @property
    def text(self) -> str:
        if self._live is None:
            return self._text
        fd, start = self._live
        end = os.lseek(fd, 0, os.SEEK_END)
        return self._text + os.pread(fd, end - start, start).decode("utf-8", "replace")

    @text.setter
    def text(self, value: str) -> None:
        self._text, self._live = value, None

    def lines(self) -> list[str]:
        """The non-empty lines, without OpenCV's own log lines (``[ WARN:0@...] global ...``)."""
        return [s for line in self.text.splitlines() if (s := line.strip()) and not _OPENCV_LOG.match(s)]

    def summary(self, limit: int = 200) -> str:
        """The lines joined with ``"; "`` into one, at most ``limit`` characters ("" when there were none)."""
        text = "; ".join(dict.fromkeys(self.lines()))  # a message repeated per chunk or scanline is said once
        return text if len(text) <= limit else text[: limit - 3] + "..."


_OPENCV_LOG = re.compile(r"^\[\s*(WARN|ERROR|INFO|DEBUG)[^\]]*\]")
_capture_lock = threading.Lock()
_capture_state: dict[str, Any] = {"depth": 0, "saved": -1, "file": None}


@contextlib.contextmanager
def library_output() -> Iterator[LibraryOutput]:
    """Redirect file descriptor 2 to a temporary file around a C library call (libjpeg, libpng, OpenEXR, LibRaw,
    OpenCV print there directly, past ``sys.stderr``), and hand what they wrote back as a :class:`LibraryOutput`
    instead of letting it reach the terminal.

    Nested or concurrent blocks of one process share one redirection (the first in sets it up, the last out
    restores fd 2), so a thread's output may also show in another thread's text; processes each have their own.
    Without a usable fd 2 the block runs uncaptured.
    """
    out = LibraryOutput()
    with _capture_lock:
        state = _capture_state
        if state["depth"] == 0:
            try:
                sys.stderr.flush()
            except (AttributeError, OSError, ValueError):
                pass
            try:
                saved = os.dup(2)
            except OSError:
                saved = -1
            if saved >= 0:
                tmp = tempfile.TemporaryFile()
                os.dup2(tmp.fileno(), 2)
                state.update(saved=saved, file=tmp)
        tmp = state["file"]
        if tmp is not None:
            out._live = (tmp.fileno(), os.lseek(tmp.fileno(), 0, os.SEEK_END))
        state["depth"] += 1
    try:
        yield out
    finally:
        with _capture_lock:
            state["depth"] -= 1
            if out._live is not None:
                out.text = out.text
            if state["depth"] == 0 and state["saved"] >= 0:
                os.dup2(state["saved"], 2)
                os.close(state["saved"])
                state["file"].close()
                state.update(saved=-1, file=None)


def validation_message(exc: Exception) -> str:
    """One line ``field.path: message`` for the first error of a pydantic ``ValidationError``."""
    errors = getattr(exc, "errors", None)
    if not callable(errors) or not errors():
        return str(exc).splitlines()[0]
    first = errors()[0]
    return f"{'.'.join(str(p) for p in first['loc'])}: {first['msg']}"
