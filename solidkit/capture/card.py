"""Reading a card: which files are captures, field notes or unrelated, and the per-file ingest worker.

Files are found recursively below the card directory in sorted order. Hidden entries (``.*``,
macOS ``._*``) and files not ending in ``.jpg``/``.jpeg``/``.dng`` (any case; e.g. ``.MP4``,
``.THM``, ``.txt``) are *unrelated*: listed as skipped, never copied. Field notes files
(``fieldnotes.toml``/``.json``, :mod:`solidkit.capture.fieldnotes`) are read apart.
:func:`folder_layout` gives the scene/probe ids of the explicit folder layout
(:mod:`solidkit.capture.campaign`).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import stat
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from solidkit.camera.metadata import read_metadata
from solidkit.capture.fieldnotes import is_notes_file, read_notes
from solidkit.capture.frame_merge import sniff_format
from solidkit.envmap.io import check_image_size, jpeg_damage
from solidkit.errors import InputError, LibraryOutput, SolidkitError, library_output
from solidkit.fsutil import atomic_path, is_environmental, sha256_file

__all__ = ["IMAGE_SUFFIXES", "CardScan", "scan_card", "folder_layout", "ingest_file", "copy_original"]

IMAGE_SUFFIXES = {".jpg": ".jpg", ".jpeg": ".jpg", ".dng": ".dng"}
_DCF = re.compile(r"^\d{3}[A-Za-z0-9_]{5}$")


@dataclass
class CardScan:
    """What :func:`scan_card` found: paths relative to the card, sorted; ``skipped`` maps each
    unrelated path (file or folder) to the reason it is not ingested."""

    captures: list[Path] = field(default_factory=list)
    notes: list[Path] = field(default_factory=list)
    skipped: dict[Path, str] = field(default_factory=dict)

    @property
    def unrelated(self) -> list[Path]:
        return sorted(self.skipped)


_KINDS = (
    (stat.S_ISFIFO, "named pipe"),
    (stat.S_ISSOCK, "socket"),
    (stat.S_ISCHR, "character device"),
    (stat.S_ISBLK, "block device"),
)


def _skip_reason(path: Path, name: str, depth: int) -> str | None:
    """Why a card file is not a capture or notes file (None: it is one)."""
    st = path.lstat()
    if name.startswith("."):
        return "hidden file"
    if stat.S_ISLNK(st.st_mode):
        return "symbolic link (not followed: copy the file itself onto the card)"
    if not stat.S_ISREG(st.st_mode):
        kind = next((k for test, k in _KINDS if test(st.st_mode)), "special file")
        return f"not a regular file ({kind})"
    if Path(name).suffix.lower() in IMAGE_SUFFIXES:
        return None
    if is_notes_file(name):
        return None if depth <= 2 else "field notes below a scene folder (put them in CARD/<scene>/ or CARD/)"
    return "not a capture (.jpg/.jpeg/.dng)"


def scan_card(card: str | os.PathLike) -> CardScan:
    """Captures, field notes and skipped files below ``card``, with the reason for each skip.

    Symbolic links (to files or folders) and hidden folders are not followed; special files
    (named pipes, sockets, devices) are never opened.
    """
    card = Path(card)
    if not card.is_dir():
        raise InputError(f"{card}: not a directory")
    out = CardScan()
    for root, dirs, files in os.walk(card):
        keep = []
        for d in sorted(dirs):
            rel = Path(root, d).relative_to(card)
            if Path(root, d).is_symlink():
                out.skipped[rel] = "symbolic link to a folder (not followed: copy the folder itself onto the card)"
            elif d.startswith("."):
                out.skipped[rel] = "hidden folder (not searched)"
            else:
                keep.append(d)
        dirs[:] = keep
        for name in sorted(files):
            rel = Path(root, name).relative_to(card)
            try:
                why = _skip_reason(Path(root, name), name, len(rel.parts))
            except OSError as exc:
                why = f"unreadable ({exc.strerror or exc})"
            if why is not None:
                out.skipped[rel] = why
            elif is_notes_file(name):
                out.notes.append(rel)
            else:
                out.captures.append(rel)
    return out


def folder_layout(rel: Path) -> tuple[str | None, str | None]:
    """(scene, probe-or-'photo') from the explicit folder layout, or (None, None)."""
    parts = rel.parts[:-1]
    if not parts or parts[0].upper() == "DCIM" or _DCF.match(parts[0]):
        return None, None
    scene = parts[0]
    if len(parts) == 1 or parts[1].upper() == "DCIM" or _DCF.match(parts[1]):
        return scene, None
    return scene, ("photo" if parts[1].lower() == "photo" else parts[1])


def _check_decodable(path: Path, fmt: str, size: tuple[int, int]) -> None:
    """Decode the whole image (a truncated JPEG is an error, not a grey tail; so is data libjpeg calls corrupt).

    ``size``: ``(width, height)`` from the header, refused before decoding when empty or past
    :data:`~solidkit.envmap.io.MAX_IMAGE_PIXELS`.
    """
    try:
        check_image_size(path, size)
    except InputError as exc:
        raise InputError(str(exc).replace(f"{path}: ", "")) from None
    said = LibraryOutput()
    if fmt == "jpeg":
        from PIL import Image

        try:
            with warnings.catch_warnings(), Image.open(path) as im:
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # the size is checked above
                # DCT-domain 1/8 scaling: every entropy-coded byte is still decoded (truncation
                # and corrupt data are caught), at a fraction of the full decode's cost
                im.draft("RGB", (max(1, im.width // 8), max(1, im.height // 8)))
                im.load()
        except Exception as exc:
            raise InputError(f"cannot decode JPEG: truncated or corrupt ({type(exc).__name__}: {exc})") from None
        damage = jpeg_damage(path)  # Pillow decodes past what libjpeg reports as corrupt
        if damage:
            raise InputError(f"cannot decode JPEG: corrupt data (libjpeg: {damage})")
    else:
        import rawpy

        try:
            with library_output() as said, rawpy.imread(str(path)) as raw:
                raw.raw_image_visible.sum()
        except Exception as exc:
            printed = said.summary().replace(f"{path}: ", "")
            detail = f"{type(exc).__name__}: {exc}" + (f"; LibRaw: {printed}" if printed else "")
            raise InputError(f"cannot decode raw data ({detail})") from None


def copy_original(src: Path, dest: Path, sha: str) -> bool:
    """Copy ``src`` to ``dest`` atomically, verify its sha256, make it read-only and give it the
    card file's modification time (so that a size and time check finds it intact later:
    :mod:`solidkit.capture.verify`). False if present: a file of the same size and time, or one
    whose content hashes to ``sha`` (it gets the card file's time)."""
    src_st = src.stat()
    if dest.exists():
        st = dest.stat()
        if st.st_size == src_st.st_size:
            if st.st_mtime_ns == src_st.st_mtime_ns:
                return False
            if sha256_file(dest) == sha:
                with contextlib.suppress(OSError):
                    os.utime(dest, ns=(src_st.st_atime_ns, src_st.st_mtime_ns))
                return False
        dest.chmod(stat.S_IWUSR | stat.S_IRUSR)  # a wrong file under a content name: replace it
        dest.unlink()
    with atomic_path(dest) as tmp:
        h = hashlib.sha256()
        try:
            with open(src, "rb") as fi, open(tmp, "wb") as fo:
                while block := fi.read(1 << 20):  # hash exactly the bytes written
                    h.update(block)
                    fo.write(block)
                fo.flush()
                os.fsync(fo.fileno())
        except OSError as exc:
            exc.needed_bytes = src_st.st_size  # type: ignore[attr-defined]
            raise
        if h.hexdigest() != sha:
            raise InputError("copy verification failed: the file changed while it was being ingested")
        tmp.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
        os.utime(tmp, ns=(src_st.st_atime_ns, src_st.st_mtime_ns))
    return True


def ingest_file(card: str, rel: str, campaign: str, throttle_s: float = 0.0) -> dict[str, Any]:
    """Worker: hash, validate, read metadata, copy.

    Returns ``{"shot": ..., "copied": bool}``, ``{"error": ...}`` (a problem of the file itself:
    remembered) or ``{"transient": ...}`` (an environmental OS error: retried next run).
    """
    src = Path(card) / rel
    try:
        st = src.stat()
    except OSError as exc:  # vanished or unreadable since the scan: try again next run
        return {
            "transient": {
                "card": card,
                "path": rel,
                "size": 0,
                "mtime_ns": 0,
                "message": f"I/O error: {exc.strerror or exc}",
            }
        }
    ref = {"card": card, "path": rel, "size": st.st_size, "mtime_ns": st.st_mtime_ns}
    try:
        if throttle_s:
            time.sleep(throttle_s)
        if st.st_size == 0:
            raise InputError("empty file (0 bytes)")
        kind = sniff_format(src)
        suffix = IMAGE_SUFFIXES[src.suffix.lower()]
        if suffix == ".jpg" and kind == "tiff":
            raise InputError(f"content is TIFF/DNG (raw) but the name ends in {src.suffix}; rename it to .dng")
        if suffix == ".jpg" and kind != "jpeg":
            raise InputError("not a JPEG file (bad signature)")
        if suffix == ".dng" and kind != "tiff":
            raise InputError("not a DNG file (no TIFF signature)")
        sha = sha256_file(src)
        meta = read_metadata(src)
        _check_decodable(src, "jpeg" if suffix == ".jpg" else "raw", (meta.width, meta.height))
        original = Path("originals") / sha[:2] / f"{sha}{suffix}"
        copied = copy_original(src, Path(campaign) / original, sha)
        md = meta.model_dump(mode="json")
        md["path"] = original.as_posix()
        return {
            "shot": {
                "sha256": sha,
                "original": original.as_posix(),
                "size": st.st_size,
                "file_format": md.get("file_format", "jpeg"),
                "sources": [ref],
                "metadata": md,
            },
            "copied": copied,
        }
    except SolidkitError as exc:
        return {"error": {**ref, "message": str(exc).replace(str(src) + ": ", "")}}
    except OSError as exc:
        # disk full, read-only campaign, permissions, a failing card reader: retried on the next
        # run (not remembered); any other OS error belongs to the file and is remembered
        key = "transient" if is_environmental(exc) else "error"
        return {key: {**ref, "message": f"I/O error: {exc.strerror or exc}"}}


def ingest_notes(card: str, rel: str, campaign: str) -> dict[str, Any]:
    """Read one field notes file: copy it read-only beside the originals and validate it.

    Returns a :class:`~solidkit.capture.manifest.FieldNotesRecord` as a dict; a file that does
    not parse or validate gets ``error`` (one line) and no ``notes``. A notes file at the card's
    top level is a card-level file (``[scenes.<id>]`` tables), one in a scene folder belongs to
    that scene.
    """
    src = Path(card) / rel
    parts = Path(rel).parts
    scene = parts[0] if len(parts) == 2 else None
    record: dict[str, Any] = {"card": card, "path": rel, "sha256": "", "scene": scene}
    try:
        record["sha256"] = sha = sha256_file(src)
        original = Path("originals") / sha[:2] / f"{sha}{src.suffix.lower()}"
        copy_original(src, Path(campaign) / original, sha)
        record["original"] = original.as_posix()
        record["notes"] = read_notes(src, card_level=scene is None).model_dump(mode="json")
    except SolidkitError as exc:
        record["error"] = f"{rel}: {str(exc).split(': ', 1)[-1]}"
    except OSError as exc:
        record["error"] = f"{rel}: I/O error: {exc.strerror or exc}"
    return record
