"""Atomic, idempotent file writing: nothing half-written ever appears under its final name."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import mmap
import os
import stat
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

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


#: errno values that mean the disk (or the quota) is full: their messages say how much space is missing.
SPACE_ERRNOS = frozenset(getattr(errno, name) for name in ("ENOSPC", "EDQUOT") if hasattr(errno, name))


def free_bytes(path: str | os.PathLike) -> int | None:
    """Bytes an unprivileged writer may still use on the file system holding ``path`` (or its nearest
    existing parent); ``None`` when the system cannot say."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        st = os.statvfs(p)
    except (OSError, AttributeError):
        return None
    return st.f_bavail * st.f_frsize


def format_bytes(n: float) -> str:
    """``n`` bytes for people: ``512 B``, ``3.1 kB``, ``6.3 MB``, ``1.2 GB`` (powers of 1000)."""
    for unit in ("B", "kB", "MB", "GB"):
        if abs(n) < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    raise AssertionError("unreachable")


def errno_from_message(message: str) -> int | None:
    """The environmental errno whose text (``os.strerror``) a library's message quotes, e.g. OpenEXR's
    ``Failed to write pixel data to image file "x". No space left on device.``; ``None`` if none."""
    low = message.lower()
    for code in sorted(ENVIRONMENTAL_ERRNOS):
        if os.strerror(code).lower() in low:
            return code
    return None


def write_error(exc: OSError, final: str | os.PathLike, needed: int | None = None) -> OSError:
    """``exc`` (raised while writing a temporary beside ``final``) as an error about ``final`` itself.

    The same errno (and so the same ``OSError`` subclass), ``filename`` the final path; a space error
    (:data:`SPACE_ERRNOS`) says how much is free and, when ``needed`` (bytes, an estimate) is known,
    how much the file needs: ``No space left on device (needs about 6.3 MB, 120.0 kB free)``. A
    writer passes it through :func:`atomic_path` as the attribute ``needed_bytes`` of the error it raises.
    """
    code = exc.errno if exc.errno is not None else errno.EIO
    reason = exc.strerror or os.strerror(code)
    if code in SPACE_ERRNOS and "free)" not in reason:
        free = free_bytes(Path(final).parent)
        parts = [f"needs about {format_bytes(needed)}" if needed is not None else None]
        parts.append(f"{format_bytes(free)} free" if free is not None else None)
        if any(parts):
            reason += f" ({', '.join(p for p in parts if p)})"
    out = OSError(code, reason, str(final))
    out.__cause__ = exc
    return out


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
    On any exception the temporary file is removed and ``path`` is left untouched; an ``OSError``
    (disk full, permissions, I/O) comes out about ``path``, never the temporary
    (:func:`write_error`; a writer may set ``needed_bytes`` on the error it raises). The file gets
    the permissions a plainly created file would (``0666 & ~umask``) unless the caller changed
    the temporary's mode (e.g. read-only originals); ``mkstemp``'s private 0600 never leaks out.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=path.parent)
    except OSError as exc:  # about the folder (a file where it should be, permissions) or the temporary
        temporary = exc.filename is not None and Path(exc.filename).name.startswith(f".{path.name}.")
        raise write_error(exc, path if exc.filename is None or temporary else exc.filename) from exc
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if tmp_path.exists() and stat.S_IMODE(tmp_path.stat().st_mode) == 0o600:
            tmp_path.chmod(0o666 & ~_umask())
        os.replace(tmp_path, path)
    except OSError as exc:
        _remove(tmp_path)
        if exc.filename is not None and Path(exc.filename) not in (tmp_path, path):
            raise  # about another file (e.g. a source being read)
        raise write_error(exc, path, getattr(exc, "needed_bytes", None)) from exc
    except BaseException:
        _remove(tmp_path)
        raise


def _remove(tmp: Path) -> None:
    with contextlib.suppress(OSError):  # a failed clean-up must not hide the error being raised
        tmp.unlink(missing_ok=True)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (fsync before the rename); a failure says how much space
    the file needs (:func:`write_error`)."""
    with atomic_path(path) as tmp:
        try:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            exc.needed_bytes = len(data)  # type: ignore[attr-defined]
            raise


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


class LockBusy(Exception):
    """:func:`file_lock`: another process holds the lock; ``holder`` is what it wrote into the lock
    file (``{}`` when it has not written yet)."""

    def __init__(self, path: Path, holder: dict[str, Any]):
        super().__init__(f"{path}: locked by {holder or 'another process'}")
        self.path, self.holder = path, holder


_HELD: dict[tuple[int, int], int] = {}  # (st_dev, st_ino) of the lock files this process holds -> depth
_HELD_GUARD = threading.Lock()


def read_lock_holder(path: str | os.PathLike) -> dict[str, Any]:
    """What the holder of the lock file ``path`` wrote into it (``{}``: nothing, or not JSON)."""
    try:
        data = json.loads(Path(path).read_text() or "{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


@contextlib.contextmanager
def file_lock(
    path: str | os.PathLike,
    holder: dict[str, Any],
    *,
    wait: bool = False,
    on_wait: Callable[[dict[str, Any]], None] | None = None,
) -> Iterator[None]:
    """Hold an exclusive ``flock`` on the file ``path`` (created) while the block runs.

    ``holder`` (JSON) is written into the file while it is held, for the message of a process
    refused (:class:`LockBusy`) or, with ``wait``, queued behind it (``on_wait(holder)`` is called
    once before waiting). The file is left as found (empty, its time unchanged) on release; the
    kernel releases the lock of a killed process. A process that holds the lock already enters
    again (a step run inside another). A lock file that cannot be created or written (a read-only
    campaign: nobody can write it) is taken read-only, or not at all.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(path, "a+")
        writable = True
    except OSError as exc:
        if exc.errno not in (errno.EACCES, errno.EPERM, errno.EROFS):
            raise
        try:
            fh, writable = open(path), False
        except OSError:
            yield
            return
    with fh:
        st = os.fstat(fh.fileno())
        key = (st.st_dev, st.st_ino)
        with _HELD_GUARD:
            depth = _HELD.get(key, 0)
            if depth:
                _HELD[key] = depth + 1
        if depth:
            try:
                yield
            finally:
                with _HELD_GUARD:
                    _HELD[key] -= 1
            return
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            found = read_lock_holder(path)
            if not wait:
                raise LockBusy(path, found) from None
            if on_wait is not None:
                on_wait(found)
            fcntl.flock(fh, fcntl.LOCK_EX)
        with _HELD_GUARD:
            _HELD[key] = 1
        try:
            if writable:
                with contextlib.suppress(OSError):  # a full disk: held all the same, without the note
                    fh.seek(0)
                    fh.truncate()
                    fh.write(json.dumps(holder, sort_keys=True))
                    fh.flush()
            yield
        finally:
            with _HELD_GUARD:
                del _HELD[key]
            if writable:
                with contextlib.suppress(OSError):  # as found: empty, its time unchanged
                    fh.truncate(0)
                    os.utime(fh.fileno(), ns=(st.st_atime_ns, st.st_mtime_ns))
            fcntl.flock(fh, fcntl.LOCK_UN)
