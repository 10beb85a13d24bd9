"""A disk that fills up at one write site of ingest: each writer patched to fail the way its library
fails on a full disk, and a small card that reaches every site.

Write sites (:data:`SITES`): a stored capture (``original``: ``open(...).write`` in
``capture.card``), a field notes copy (``fieldnotes``: the same writer), a profile copy
(``profile``: ``shutil.copyfile``), an HDR product (``hdr``: OpenEXR raises ``RuntimeError('Failed
to write pixel data to image file "<temporary>". No space left on device.')``), a sun-frame PNG
(``sun_frame``: ``cv2.imwrite`` returns ``False`` after libpng's "Write Error") and the manifest
(``manifest``: ``open(...).write`` in ``fsutil``). From the first write at the chosen site (after
``after`` successful ones there) every write of every site fails (``sticky``: the disk stays full),
or only those of that site (a big file that does not fit while the small ones after it do, as when
the failed temporary is removed), and the free space reads 0 B, until :meth:`FullDisk.free`.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import sys
import types
from collections import Counter
from datetime import datetime, timedelta
from pathlib import Path

import cv2
import numpy as np
import pytest

SITES = ("original", "fieldnotes", "profile", "hdr", "sun_frame", "manifest")
T0 = datetime(2024, 6, 1, 12, 0, 0)


def _enospc() -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # what write(2) gives: no file name


class _FailingFile:
    """A file object whose writes fail once the disk is full."""

    def __init__(self, f, disk: FullDisk, site: str):
        self._f, self._disk, self._site = f, disk, site

    def write(self, data):
        if self._disk.hit(self._site):
            self._f.write(data[: len(data) // 2])  # part of it lands, as on a real disk
            raise _enospc()
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()
        return False


class FullDisk:
    """Ingest's writers patched so that the disk fills at ``site`` (module doc); a context manager
    (space freed on leaving it)."""

    def __init__(self, site: str, after: int = 0, sticky: bool = True):
        assert site in SITES, site
        self.site, self.after, self.sticky, self.full = site, after, sticky, False
        self.seen: Counter[str] = Counter()
        self.failed: Counter[str] = Counter()
        self._mp = pytest.MonkeyPatch()
        self._patch()

    def __enter__(self) -> FullDisk:
        return self

    def __exit__(self, *exc) -> None:
        self.free()

    def hit(self, site: str) -> bool:
        """A write at ``site``: does it fail?"""
        n = self.seen[site]
        self.seen[site] += 1
        fail = site == self.site and n >= self.after
        self.full |= fail
        fail = fail or (self.full and self.sticky)
        self.failed[site] += fail
        return fail

    def free(self) -> None:
        """Space freed: every writer works again."""
        self._mp.undo()
        self.full = False

    def _patch(self) -> None:
        import solidkit.capture.card as card_mod
        import solidkit.envmap.io as io_mod
        import solidkit.fsutil as fsutil_mod

        mp, disk = self._mp, self
        real_open = open

        def card_open(file, mode="r", *args, **kwargs):
            f = real_open(file, mode, *args, **kwargs)
            if "w" not in mode:
                return f
            site = "fieldnotes" if Path(file).suffix.lower() in (".toml", ".json") else "original"
            return _FailingFile(f, disk, site)

        def fsutil_open(file, mode="r", *args, **kwargs):
            f = real_open(file, mode, *args, **kwargs)
            if "w" in mode and Path(file).name.startswith(".manifest.json."):
                return _FailingFile(f, disk, "manifest")
            return f

        mp.setattr(card_mod, "open", card_open, raising=False)
        mp.setattr(fsutil_mod, "open", fsutil_open, raising=False)

        real_copyfile = shutil.copyfile

        def copyfile(src, dst, *args, **kwargs):
            if disk.hit("profile"):
                Path(dst).write_bytes(b"")
                raise _enospc()
            return real_copyfile(src, dst, *args, **kwargs)

        mp.setattr(shutil, "copyfile", copyfile)

        real_imwrite = cv2.imwrite

        def imwrite(path, img, params=()):
            if disk.hit("sun_frame"):
                Path(path).write_bytes(b"\x89PNG\r\n\x1a\n")
                print("libpng error: Write Error", file=sys.stderr)
                return False
            return real_imwrite(path, img, params)

        mp.setattr(cv2, "imwrite", imwrite)

        import OpenEXR as real_exr

        class File:
            def __init__(self, *args, **kwargs):
                self._f = real_exr.File(*args, **kwargs)

            def write(self, path):
                if disk.hit("hdr"):
                    Path(path).write_bytes(b"\x76\x2f\x31\x01")
                    raise RuntimeError(f'Failed to write pixel data to image file "{path}". No space left on device.')
                return self._f.write(path)

            def __getattr__(self, name):
                return getattr(self._f, name)

            def __enter__(self):
                self._f.__enter__()
                return self

            def __exit__(self, *exc):
                return self._f.__exit__(*exc)

        fake = types.ModuleType("OpenEXR")
        fake.__dict__.update({k: v for k, v in vars(real_exr).items() if not k.startswith("__")})
        fake.File = File
        mp.setitem(sys.modules, "OpenEXR", fake)
        if hasattr(io_mod, "OpenEXR"):
            mp.setattr(io_mod, "OpenEXR", fake)

        def free_bytes(path):
            return 0 if disk.full else real_free(path)

        real_free = fsutil_mod.free_bytes
        mp.setattr(fsutil_mod, "free_bytes", free_bytes)
        mp.setattr(io_mod, "free_bytes", free_bytes)


def make_fault_card(root: Path) -> tuple[Path, Path]:
    """A small card in the folder layout that reaches every write site, and a response curve file for
    ``--response``: scene ``s1`` with a photo, field notes and one Theta position ``p1`` holding a
    2-shot dual-fisheye bracket and a dual-fisheye sun frame (unwarped: a PNG product)."""
    from solidkit.camera.lens import load_profile
    from solidkit.capture.unwarp import encode_srgb8, render_fisheye
    from solidkit.envmap.coords import direction_grid
    from solidkit.envmap.io import srgb_decode
    from solidkit.synth.exif import exif_app1, insert_app1

    d = direction_grid(32)
    radiance = np.stack([1.0 + 0.5 * d[..., 0], 1.0 - 0.5 * d[..., 1], 1.0 + 0.5 * d[..., 2]], -1) * 40.0
    radiance[4:7, 20:24] = 5e4  # the sun
    fish = render_fisheye(radiance.astype(np.float32), load_profile("theta-v"), (128, 64))
    p1 = root / "s1" / "p1"
    p1.mkdir(parents=True)
    for i, t in enumerate((1 / 500, 1 / 125, 1 / 8000)):
        ok, jpg = cv2.imencode(".jpg", cv2.cvtColor(encode_srgb8(fish * t), cv2.COLOR_RGB2BGR))
        app1 = exif_app1(
            make="RICOH",
            model="RICOH THETA V",
            when=T0 + timedelta(seconds=i if i < 2 else 30),
            exposure_time=t,
            f_number=2.0,
            iso=100,
            theta={"image_type": 2, "roll_deg": 0.0, "pitch_deg": 0.0},
        )
        (p1 / f"R00100{i + 1:02d}.JPG").write_bytes(insert_app1(jpg.tobytes(), app1))
    photo = root / "s1" / "photo"
    photo.mkdir()
    ok, jpg = cv2.imencode(".jpg", (np.indices((48, 64)).sum(0) % 256).astype(np.uint8))
    app1 = exif_app1(
        make="Canon", model="EOS R", when=T0 + timedelta(seconds=60), exposure_time=1 / 200, f_number=4.0, iso=100
    )
    (photo / "IMG_0001.JPG").write_bytes(insert_app1(jpg.tobytes(), app1))
    (root / "s1" / "fieldnotes.toml").write_text(
        'fieldnotes = 1\nphoto = "IMG_0001.JPG"\nnotes = "a test scene"\n\n[probes."p1"]\npixel = [20.0, 30.0]\n'
    )
    curve = np.repeat(srgb_decode(np.arange(256) / 255.0)[:, None], 3, axis=1)
    response = root.parent / "response.json"
    response.write_text(json.dumps(curve.tolist()))
    return root, response


def campaign_files(camp: Path) -> dict[str, bytes]:
    """Every file of a campaign (relative POSIX path -> bytes); the lock file included (empty at rest)."""
    return {p.relative_to(camp).as_posix(): p.read_bytes() for p in sorted(camp.rglob("*")) if p.is_file()}
