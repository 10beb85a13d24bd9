"""``solidkit testset validate OUT``: every problem of a test set, with its scene and file.

Checks, in order (a failing schema stops the rest; everything else is reported together):

- **schema**: ``testset.json`` parses under :class:`~solidkit.testset.schema.TestSet`, same format,
  schema and conventions version;
- **files**: every file named by the manifest is listed in ``files``; every listed file exists
  with its size and SHA-256; no unlisted file lies in the folder; ``dataset_version`` is the
  content hash;
- **images**: the photo is 320x240 and photo_full has its recorded size; probes are 256x128
  equirect (full size as recorded), masks match their probe's size, HDR probes are finite and
  non-negative;
- **geometry**: rotations are orthonormal with determinant +1 (tolerance :data:`ORTHO_TOL`);
  K has positive focal lengths; the 320x240 pixel and the full-size pixel are the same ray
  (``K K_full⁻¹``, :data:`PIXEL_TOL` px); pixels lie inside their image; probe pixels are not on
  the sky (:mod:`solidkit.testset.sky`); the sun is above the horizon, its direction matches its
  angles and a sun that was not found has no angles;
- **exposure**: exposures positive and finite, the HDR bracket distinct, the sun frame not longer
  than the bracket's shortest exposure (it is the low-exposure frame), and the sun panorama's
  exposure equal to its capture's sun frame;
- **flags**: labels and alignments still flagged (skipped with ``allow_flagged``).
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from solidkit.envmap.coords import direction_from_angles
from solidkit.envmap.io import imread, read_exr
from solidkit.errors import InputError
from solidkit.fsutil import sha256_file
from solidkit.testset.build import MANIFEST_FILE, load_testset, pixel_to_model
from solidkit.testset.schema import MODEL_INPUT_SIZE, PROBE_SIZE, Probe, Scene, TestSet, content_version
from solidkit.testset.sky import on_sky, sky_mask

__all__ = ["Problem", "validate_testset", "ORTHO_TOL", "PIXEL_TOL"]

ORTHO_TOL = 1e-6  # max |RᵀR - I| entry
PIXEL_TOL = 0.01  # px, between the stored 320x240 pixel and the one implied by pixel_full
DIRECTION_TOL_DEG = 0.01


@dataclass(frozen=True)
class Problem:
    """One problem: which check, scene (or None), file (or None) and a one-line message."""

    check: str
    scene: str | None
    file: str | None
    message: str

    def __str__(self) -> str:
        where = " ".join(x for x in (self.scene, self.file) if x)
        return f"[{self.check}] {where + ': ' if where else ''}{self.message}"

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


class _Checker:
    def __init__(self, root: Path, ts: TestSet, allow_flagged: bool):
        self.root = root
        self.ts = ts
        self.allow_flagged = allow_flagged
        self.problems: list[Problem] = []
        self.bad_files: set[str] = set()

    def add(self, check: str, scene: str | None, file: str | None, message: str) -> None:
        self.problems.append(Problem(check, scene, file, message))

    # -- files
    def files(self) -> None:
        ts, root = self.ts, self.root
        if ts.dataset_version != content_version(ts):
            self.add(
                "files",
                None,
                MANIFEST_FILE,
                f"dataset_version {ts.dataset_version} is not the content hash {content_version(ts)}",
            )
        for rel, entry in ts.files.items():
            p = root / rel
            why = _unsafe_path(root, rel)
            if why:
                self.add("files", _scene_of(rel), rel, why)
                self.bad_files.add(rel)
            elif not p.is_file():
                self.add("files", _scene_of(rel), rel, "missing")
                self.bad_files.add(rel)
            elif p.stat().st_size != entry.bytes or sha256_file(p) != entry.sha256:
                self.add("files", _scene_of(rel), rel, "checksum mismatch (changed or corrupt)")
                self.bad_files.add(rel)
        on_disk = {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() or p.is_symlink()}
        on_disk -= {MANIFEST_FILE}
        for rel in sorted(on_disk - set(ts.files)):
            self.add("files", _scene_of(rel), rel, "not listed in testset.json")
        for scene in ts.scenes:
            for rel in _paths(scene):
                if rel not in ts.files:
                    self.add("files", scene.id, rel, "named in the manifest but not listed in files")
                    self.bad_files.add(rel)
        for prof in ts.profiles:
            if prof.path and prof.path not in ts.files:
                self.add("files", None, prof.path, "profile named but not listed in files")
            elif prof.path and prof.sha256 and ts.files[prof.path].sha256 != prof.sha256:
                self.add(
                    "files",
                    None,
                    prof.path,
                    f"{prof.role} profile {prof.name}: content hash differs from the one recorded",
                )

    def _image(self, scene: str, rel: str | None, hdr: bool = False) -> np.ndarray | None:
        if rel is None or rel in self.bad_files:
            return None
        try:
            return read_exr(self.root / rel)[0] if hdr else imread(self.root / rel)
        except InputError as exc:
            self.add("images", scene, rel, str(exc))
            return None

    # -- per scene
    def scene(self, s: Scene) -> None:
        photo = self._image(s.id, s.photo)
        if photo is not None and (photo.shape[1], photo.shape[0]) != MODEL_INPUT_SIZE:
            self.add(
                "images",
                s.id,
                s.photo,
                f"is {photo.shape[1]}x{photo.shape[0]}, expected {MODEL_INPUT_SIZE[0]}x{MODEL_INPUT_SIZE[1]}",
            )
        full = self._image(s.id, s.photo_full)
        if full is not None and (full.shape[1], full.shape[0]) != tuple(s.photo_full_size):
            self.add(
                "images",
                s.id,
                s.photo_full,
                f"is {full.shape[1]}x{full.shape[0]}, recorded {s.photo_full_size[0]}x{s.photo_full_size[1]}",
            )
            full = None
        K, K_full = np.asarray(s.K), np.asarray(s.K_full)
        for name, M in (("K", K), ("K_full", K_full)):
            if not (M[0, 0] > 0 and M[1, 1] > 0 and abs(M[2, 2] - 1) < 1e-9 and not M[2, :2].any()):
                self.add(
                    "geometry",
                    s.id,
                    MANIFEST_FILE,
                    f"{name} is not an intrinsics matrix (positive focal lengths, last row 0 0 1)",
                )
        sky = None
        if full is not None:
            rgb = full[..., ::-1] if full.ndim == 3 else np.repeat(full[..., None], 3, -1)
            sky = sky_mask(rgb, K_full, s.pitch_deg, s.roll_deg)
        captures = [(p.id, p.rotation, p.images, p.capture, p.alignment.flags) for p in s.probes]
        if s.camera is not None:
            captures.append(
                (s.camera.id, s.camera.rotation, s.camera.images, s.camera.capture, s.camera.alignment.flags)
            )
        for pid, rotation, images, capture, _ in captures:
            self.rotation(s.id, pid, rotation)
            self.images(s.id, pid, images)
            self.exposure(s.id, pid, capture)
        for p in s.probes:
            self.pixel(s, p, K, K_full, sky)
        self.sun(s)
        if s.capture.exposure.exposure_time_s is not None:
            e = s.capture.exposure
            for name, v in (("exposure_time_s", e.exposure_time_s), ("f_number", e.f_number), ("iso", e.iso)):
                if v is not None and not (math.isfinite(v) and v > 0):
                    self.add("exposure", s.id, s.photo_full, f"photo {name} = {v} is not positive")
        if not self.allow_flagged:
            for what, flags in (
                [("scene", s.flags), ("sun", s.sun.flags)]
                + [(f"probe {p.id}", p.flags) for p in s.probes]
                + ([("camera capture", s.camera.alignment.flags)] if s.camera else [])
            ):
                if flags:
                    self.add(
                        "flags",
                        s.id,
                        MANIFEST_FILE,
                        f"{what} still flagged: {', '.join(flags)} (review, or --allow-flagged)",
                    )

    def rotation(self, sid: str, pid: str, rotation: list[list[float]]) -> None:
        R = np.asarray(rotation, np.float64)
        err = float(np.max(np.abs(R.T @ R - np.eye(3))))
        if err > ORTHO_TOL:
            self.add("geometry", sid, MANIFEST_FILE, f"{pid}: rotation is not orthonormal (max |RᵀR - I| = {err:.2g})")
        elif np.linalg.det(R) < 0:
            self.add("geometry", sid, MANIFEST_FILE, f"{pid}: rotation is a reflection (det = -1)")

    def images(self, sid: str, pid: str, im) -> None:
        want = {"ldr": (PROBE_SIZE[1], PROBE_SIZE[0]), "ldr_full": (im.ldr_full_size[1], im.ldr_full_size[0])}
        shapes = {}
        for name, rel, hdr in (
            ("ldr", im.ldr, False),
            ("ldr_full", im.ldr_full, False),
            ("hdr", im.hdr, True),
            ("hdr_full", im.hdr_full, True),
            ("saturation", im.saturation, False),
            ("saturation_full", im.saturation_full, False),
        ):
            img = self._image(sid, rel, hdr)
            if img is None:
                continue
            shapes[name] = img.shape[:2]
            expect = want["ldr_full" if name.endswith("_full") else "ldr"]
            if img.shape[:2] != expect:
                self.add(
                    "images",
                    sid,
                    rel,
                    f"{pid}: {name} is {img.shape[1]}x{img.shape[0]}, expected {expect[1]}x{expect[0]}",
                )
            if img.shape[1] != 2 * img.shape[0]:
                self.add("images", sid, rel, f"{pid}: {name} is not an equirect panorama (width != 2 x height)")
            if hdr and not (np.isfinite(img).all() and (img >= 0).all()):
                self.add("images", sid, rel, f"{pid}: {name} has NaN/Inf or negative radiance")

    def pixel(self, s: Scene, p: Probe, K: np.ndarray, K_full: np.ndarray, sky: np.ndarray | None) -> None:
        W, H = s.photo_full_size
        x, y = p.pixel_full
        if not (-0.5 <= x <= W - 0.5 and -0.5 <= y <= H - 0.5):
            self.add("geometry", s.id, s.photo_full, f"{p.id}: pixel_full ({x:.1f}, {y:.1f}) outside the {W}x{H} photo")
        w, h = MODEL_INPUT_SIZE
        xs, ys = p.pixel
        if not (-0.5 <= xs <= w - 0.5 and -0.5 <= ys <= h - 0.5):
            self.add(
                "geometry",
                s.id,
                s.photo,
                f"{p.id}: pixel ({xs:.1f}, {ys:.1f}) outside the {w}x{h} photo (cropped away)",
            )
        try:
            ex, ey = pixel_to_model(p.pixel_full, K_full, K)
        except np.linalg.LinAlgError:
            return
        if math.hypot(ex - xs, ey - ys) > PIXEL_TOL:
            self.add(
                "geometry",
                s.id,
                MANIFEST_FILE,
                f"{p.id}: pixel ({xs:.2f}, {ys:.2f}) is not pixel_full under K K_full⁻¹ ({ex:.2f}, {ey:.2f})",
            )
        if sky is not None and 0 <= round(y) < sky.shape[0] and 0 <= round(x) < sky.shape[1] and on_sky(sky, x, y):
            self.add("geometry", s.id, s.photo_full, f"{p.id}: pixel ({x:.0f}, {y:.0f}) is on the sky")

    def sun(self, s: Scene) -> None:
        sun = s.sun
        if not sun.found:
            if sun.azimuth_deg is not None or sun.elevation_deg is not None:
                self.add("geometry", s.id, MANIFEST_FILE, "sun not found but has angles")
            return
        if sun.azimuth_deg is None or sun.elevation_deg is None:
            self.add("geometry", s.id, MANIFEST_FILE, "sun found without azimuth/elevation")
            return
        if not (sun.elevation_deg > 0.0):
            self.add(
                "geometry", s.id, MANIFEST_FILE, f"sun elevation {sun.elevation_deg:.2f} deg is not above the horizon"
            )
        if not -180.0 <= sun.azimuth_deg < 180.0:
            self.add("geometry", s.id, MANIFEST_FILE, f"sun azimuth {sun.azimuth_deg:.2f} deg outside [-180, 180)")
        if sun.uncertainty_deg is not None and not (math.isfinite(sun.uncertainty_deg) and sun.uncertainty_deg >= 0):
            self.add(
                "geometry", s.id, MANIFEST_FILE, f"sun uncertainty {sun.uncertainty_deg} is not a non-negative angle"
            )
        if sun.direction is not None:
            d = np.asarray(direction_from_angles(math.radians(sun.azimuth_deg), math.radians(sun.elevation_deg)))
            v = np.asarray(sun.direction, np.float64)
            n = float(np.linalg.norm(v))
            ang = math.degrees(math.acos(float(np.clip(v @ d / n, -1, 1)))) if n > 0 else 180.0
            if abs(n - 1) > 1e-6 or ang > DIRECTION_TOL_DEG:
                self.add(
                    "geometry",
                    s.id,
                    MANIFEST_FILE,
                    f"sun direction disagrees with its azimuth/elevation by {ang:.3f} deg",
                )

    def exposure(self, sid: str, pid: str, cap) -> None:
        br = cap.bracket_exposures_s
        if any(not (math.isfinite(t) and t > 0) for t in br):
            self.add("exposure", sid, MANIFEST_FILE, f"{pid}: bracket exposure times must be positive ({br})")
            return
        if len(set(br)) != len(br):
            self.add("exposure", sid, MANIFEST_FILE, f"{pid}: bracket repeats an exposure time ({br})")
        sf = cap.sun_frame_exposure
        if sf is not None and sf.exposure_time_s is not None:
            if not (math.isfinite(sf.exposure_time_s) and sf.exposure_time_s > 0):
                self.add(
                    "exposure", sid, MANIFEST_FILE, f"{pid}: sun frame exposure {sf.exposure_time_s} s is not positive"
                )
            elif br and sf.exposure_time_s > min(br) * (1 + 1e-9):
                self.add(
                    "exposure",
                    sid,
                    MANIFEST_FILE,
                    f"{pid}: sun frame exposure {sf.exposure_time_s:.3g} s is longer than the bracket's shortest "
                    f"{min(br):.3g} s",
                )

    def sun_panorama_exposure(self, s: Scene) -> None:
        sun = s.sun
        if sun.panorama is None or sun.panorama_capture is None:
            return
        caps = {p.id: p.capture for p in s.probes}
        if s.camera is not None:
            caps[s.camera.id] = s.camera.capture
        cap = caps.get(sun.panorama_capture)
        if cap is None:
            self.add(
                "exposure",
                s.id,
                sun.panorama,
                f"sun panorama from capture {sun.panorama_capture!r}, which the scene lacks",
            )
        elif cap.sun_frame_exposure is not None and sun.panorama_exposure != cap.sun_frame_exposure:
            self.add(
                "exposure", s.id, sun.panorama, "sun panorama exposure differs from its capture's sun frame exposure"
            )


def _paths(scene: Scene) -> list[str]:
    out = [scene.photo, scene.photo_full]
    if scene.sun.panorama:
        out.append(scene.sun.panorama)
    caps = [p.images for p in scene.probes] + ([scene.camera.images] if scene.camera else [])
    for im in caps:
        out += [x for x in (im.ldr, im.ldr_full, im.hdr, im.hdr_full, im.saturation, im.saturation_full) if x]
    for p in scene.probes:
        if p.ldr != p.images.ldr or p.hdr != p.images.hdr:
            out.append(p.ldr)
    return out


def _unsafe_path(root: Path, rel: str) -> str | None:
    """Why the file entry ``rel`` must not be opened (``None``: a plain file path inside the test set)."""
    parts = PurePosixPath(rel).parts
    if not rel or PurePosixPath(rel).is_absolute() or "\\" in rel or ":" in (parts[0] if parts else ""):
        return "not a relative path inside the test set (absolute, or a drive or backslash)"
    if ".." in parts:
        return "a path that leaves the test set ('..')"
    p = root
    for part in parts:
        p = p / part
        if p.is_symlink():
            return f"a link ({p.relative_to(root).as_posix()} -> {os.readlink(p)}): a test set holds plain files only"
    return None


def _scene_of(rel: str) -> str | None:
    parts = rel.split("/")
    return parts[1] if len(parts) > 2 and parts[0] == "scenes" else None


def validate_testset(root: str | os.PathLike, *, allow_flagged: bool = False) -> list[Problem]:
    """All problems of the test set at ``root`` (empty list: valid). See the module docstring.

    Raises :class:`InputError` when ``root`` holds no ``testset.json`` at all (not a test set);
    a manifest that does not parse is a ``schema`` problem.
    """
    root = Path(root)
    if not (root / MANIFEST_FILE).is_file():
        raise InputError(f"{root}: not a test set (no {MANIFEST_FILE})")
    try:
        ts = load_testset(root)
    except InputError as exc:
        return [Problem("schema", None, MANIFEST_FILE, str(exc))]
    c = _Checker(root, ts, allow_flagged)
    c.files()
    for s in ts.scenes:
        for p in s.probes:
            if p.ldr != p.images.ldr or p.hdr != p.images.hdr:
                c.add("schema", s.id, MANIFEST_FILE, f"{p.id}: ldr/hdr differ from images.ldr/images.hdr")
        c.scene(s)
        c.sun_panorama_exposure(s)
    ids = [s.id for s in ts.scenes]
    if len(set(ids)) != len(ids):
        c.add("schema", None, MANIFEST_FILE, "scene ids are not unique")
    for s in ts.scenes:
        pids = [p.id for p in s.probes]
        for pid in sorted({p for p in pids if pids.count(p) > 1}):
            c.add("schema", s.id, MANIFEST_FILE, f"probe {pid} is listed {pids.count(pid)} times")
    return c.problems
