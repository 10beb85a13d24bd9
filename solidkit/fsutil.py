"""Atomic, idempotent file writing: nothing half-written ever appears under its final name."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import mmap
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

#: errno values that say something about the machine (space, quota, media, permissions, limits),
#: not about the file being processed: worth retrying once the environment is fixed.
ENVIRONMENTAL_ERRNOS = frozenset(
    getattr(errno, name)
    for name in (
        "ENOSPC",
        "EDQUOT",
        "EIO",
        "EROFS",
        "EACCES",
        "EPERM",
        "ENOMEM",
        "EMFILE",
        "ENFILE",
        "EAGAIN",
        "ETIMEDOUT",
        "ENOTCONN",
        "ESTALE",
        "EBUSY",
        "ENXIO",
    )
    if hasattr(errno, name)
)


def is_environmental(exc: BaseException) -> bool:
    """Is ``exc`` an OS error of the environment (disk full, read-only, permissions, I/O) rather
    than of the data (see :data:`ENVIRONMENTAL_ERRNOS`)?"""
    return isinstance(exc, OSError) and exc.errno in ENVIRONMENTAL_ERRNOS


def _umask() -> int:
    """The process umask, read without changing it (Linux ``/proc``; else set and restore)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed onto ``path``.

    The temporary file keeps ``path``'s suffix (writers such as OpenCV pick the codec from it).
    On any exception the temporary file is removed and ``path`` is left untouched. The file gets
    the permissions a plainly created file would (``0666 & ~umask``) unless the caller changed
    the temporary's mode (e.g. read-only originals); ``mkstemp``'s private 0600 never leaks out.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if tmp_path.exists() and stat.S_IMODE(tmp_path.stat().st_mode) == 0o600:
            tmp_path.chmod(0o666 & ~_umask())
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (fsync before the rename)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def jpeg_truncated(path: str | os.PathLike) -> bool:
    """True for a JPEG file (``FF D8 FF``) whose scan data has no end-of-image marker ``FF D9``:
    cut short by a failed copy or card error (decoders such as OpenCV's fill the missing rows
    with grey instead of failing).

    The marker segments before the first scan (``FF DA``) are skipped by their lengths, so an
    embedded EXIF thumbnail's own ``FF D9`` does not count; data after the end marker (phone
    trailers, motion-photo videos) is allowed. Entropy-coded data cannot contain ``FF D9``
    (ITU-T T.81 B.1.1.5: ``FF`` is stuffed as ``FF 00``).
    """
    with open(path, "rb") as f:
        if f.read(3) != b"\xff\xd8\xff":
            return False
        if os.fstat(f.fileno()).st_size < 4:
            return True
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            pos = 2
            while pos + 4 <= len(data) and data[pos] == 0xFF:
                marker = data[pos + 1]
                if marker == 0xFF:  # fill byte
                    pos += 1
                    continue
                if marker == 0xDA:
                    return data.find(b"\xff\xd9", pos) < 0
                pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
            return True  # no scan reached: headers cut short or corrupt


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's content."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()
