"""``solidkit testset build CAMPAIGN -o OUT``: assemble a versioned real test set from a campaign.

Inputs (never modified): the campaign's ``manifest.json`` (ingest), ``align/alignment.json``
(:mod:`solidkit.align.schema`) and, when present, its label store (:mod:`solidkit.labeling.store`).

Which value wins
----------------
For each probe pixel, capture yaw and scene sun the candidates are the alignment's value (with
the provenance align recorded: ``field_notes``, a label, or ``auto``) and the label store's
current label; the higher :data:`~solidkit.testset.schema.SOURCE_RANK` wins
(``reviewed > annotator > field_notes > auto``), the store on a tie (it is the later word). The
winner's source, annotator and label version are recorded in the manifest.

A capture whose yaw changed (a heading label newer than the alignment) gets its aligned
products re-rotated by ``R_y(yaw_label - yaw_align)`` (conventions §4, §8: both are rotations of
the same level frame about gravity); otherwise align's files are copied byte for byte.

What is written (layout in :mod:`solidkit.testset.schema`)
----------------------------------------------------------
The photo's original bytes and its 320x240 centre crop/resize with both K
(:func:`solidkit.calibration.camera.resize_crop`); probe pixels in both sizes (the 320x240 pixel
is ``K' K⁻¹ (x, y, 1)``: the same ray); each probe's aligned LDR (256x128 and full size), HDR
where a bracket exists, and saturation masks; the sun and the low-exposure panorama it came from
rotated into the photo's panorama frame; capture metadata and calibration profiles by hash.

Determinism and safety
----------------------
Identical inputs give byte-identical output: PNGs and EXRs carry no times, JSON is sorted, the
version is a content hash. The test set is assembled in a sibling temporary folder and swapped
in by renames, so ``OUT`` is either the old or the new test set. ``OUT`` must be absent, empty
or an earlier test set (``testset.json`` with this format); anything else is refused. A rebuild
whose content is unchanged leaves ``OUT`` untouched.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np

from solidkit import __version__
from solidkit.align.captures import normal_shot_of
from solidkit.align.schema import (
    CampaignAlignment,
    ProbeAlignment,
    SceneAlignment,
    body_to_pano,
    level_to_pano,
    load_alignment,
    wrap_deg,
)
from solidkit.calibration.camera import resize_crop
from solidkit.capture.lock import campaign_lock
from solidkit.capture.manifest import Manifest, load_manifest
from solidkit.document import read_json_object, validate_versioned
from solidkit.envmap.coords import CONVENTIONS_VERSION, direction_from_angles, solid_angle
from solidkit.envmap.io import imread, read_exr, read_ldr, write_exr, write_ldr
from solidkit.envmap.resample import rotate
from solidkit.errors import InputError
from solidkit.flags import Flag, FlagCode
from solidkit.fsutil import atomic_path, sha256_file
from solidkit.labeling.store import LabelStore, store_path
from solidkit.testset.schema import (
    FORMAT,
    GPS,
    MODEL_INPUT_SIZE,
    PROBE_SIZE,
    SCHEMA_VERSION,
    SOURCE_RANK,
    Alignment,
    CameraCapture,
    Cue,
    Exposure,
    FileEntry,
    Inputs,
    PhotoCapture,
    Probe,
    ProbeCapture,
    ProbeImages,
    ProfileRef,
    Scene,
    Sun,
    TestSet,
    canonical_json,
    content_version,
)

__all__ = ["BuildReport", "build_testset", "load_testset", "pixel_to_model", "Candidate", "choose", "merge_flags"]

MANIFEST_FILE = "testset.json"
SATURATION_LEVEL = 250  # 8-bit code value at or above which an LDR channel counts as clipped
_LABEL_SOURCE = {"field_notes": "field_notes", "geometry": "auto"}


# --------------------------------------------------------------------------- provenance
@dataclass(frozen=True)
class Candidate:
    """One candidate value with its provenance."""

    value: Any
    source: str
    annotator: str | None = None
    label_version: int | None = None
    flags: tuple[str, ...] = ()
    from_store: bool = False


def merge_flags(*lists: Any) -> list[str]:
    """Union of flag lists (stored strings), one entry per flag code (:class:`~solidkit.flags.Flag`), the most
    descriptive kept, ordered by code."""
    by_code: dict[str, str] = {}
    for flags in lists:
        for f in flags or ():
            code = Flag.parse(f).code
            if len(f) > len(by_code.get(code, "")):
                by_code[code] = f
    return [by_code[k] for k in sorted(by_code)]


def _drop(flags: Any, prefixes: tuple[str, ...]) -> list[str]:
    """``flags`` without those about a value a human has since set (codes starting with ``prefixes``)."""
    return [f for f in flags or () if not Flag.parse(f).code.startswith(prefixes)]


def choose(*candidates: Candidate | None) -> Candidate | None:
    """The winning candidate: highest :data:`SOURCE_RANK`, the label store on a tie; None if none."""
    best = None
    for c in candidates:
        if c is None:
            continue
        key = (SOURCE_RANK[c.source], c.from_store)
        if best is None or key > (SOURCE_RANK[best.source], best.from_store):
            best = c
    return best


class _Labels:
    """The label store's current labels (read-only), or nothing when the campaign has none."""

    def __init__(self, campaign: Path):
        self.labels: dict[tuple[str, str], Any] = {}
        self.used: dict[tuple[str, str], dict[str, Any]] = {}
        self.present = store_path(campaign).is_file()
        if self.present:
            for lab in LabelStore(campaign, readonly=True).list():
                self.labels[(lab.kind, lab.key)] = lab

    def candidate(self, kind: str, key: str, value: Callable[[dict[str, Any]], Any]) -> Candidate | None:
        lab = self.labels.get((kind, key))
        if lab is None:
            return None
        self.used[(kind, key)] = {
            "kind": kind,
            "key": key,
            "value": lab.value,
            "source": lab.source,
            "annotator": lab.annotator,
            "version": lab.version,
            "flags": list(lab.flags),
        }
        return Candidate(
            value(lab.value),
            lab.source,
            lab.annotator if lab.source != "auto" else None,
            lab.version,
            tuple(lab.flags),
            True,
        )

    def digest(self) -> str | None:
        if not self.present:
            return None
        used = [self.used[k] for k in sorted(self.used)]
        return hashlib.sha256(canonical_json(used).encode("utf-8")).hexdigest()


# --------------------------------------------------------------------------- geometry helpers
def pixel_to_model(pixel_full: tuple[float, float], K_full: np.ndarray, K_model: np.ndarray) -> tuple[float, float]:
    """The 320x240 pixel showing the same ray as ``pixel_full``: ``K_model K_full⁻¹ (x, y, 1)``."""
    p = np.asarray(K_model, np.float64) @ np.linalg.solve(
        np.asarray(K_full, np.float64), [pixel_full[0], pixel_full[1], 1.0]
    )
    return float(p[0] / p[2]), float(p[1] / p[2])


def _saturated_fraction(mask: np.ndarray) -> float:
    """Solid-angle-weighted share of the nonzero pixels of an equirect mask ``(H, 2H)``."""
    omega = np.asarray(solid_angle(mask.shape[0]))
    return float(np.sum(omega * (mask > 0)) / np.sum(omega))


# --------------------------------------------------------------------------- report
@dataclass
class BuildReport:
    """What a build did: counts, the excluded items with reasons, and whether OUT changed."""

    out: Path
    dataset_version: str = ""
    scenes: int = 0
    probes: int = 0
    hdr_probes: int = 0
    sun_found: int = 0
    labels_used: int = 0
    overrides: list[str] = field(default_factory=list)
    excluded: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    changed: bool = True

    def to_json(self) -> dict[str, Any]:
        return {
            "out": str(self.out),
            "dataset_version": self.dataset_version,
            "scenes": self.scenes,
            "probes": self.probes,
            "hdr_probes": self.hdr_probes,
            "sun_found": self.sun_found,
            "labels_used": self.labels_used,
            "overrides": self.overrides,
            "excluded": self.excluded,
            "warnings": self.warnings,
            "changed": self.changed,
        }


# --------------------------------------------------------------------------- the builder
class _Builder:
    def __init__(
        self, campaign: Path, staging: Path, manifest: Manifest, alignment: CampaignAlignment, report: BuildReport
    ):
        self.campaign = campaign
        self.root = staging
        self.manifest = manifest
        self.alignment = alignment
        self.report = report
        self.labels = _Labels(campaign)
        self.shots = {s.sha256: s for s in manifest.shots}

    # -- files
    def _src(self, rel: str | None, what: str) -> Path:
        if not rel:
            raise InputError(f"{what}: no file recorded")
        path = self.campaign / rel
        if not path.is_file():
            raise InputError(f"{path}: {what} is missing")
        return path

    def _copy(self, src: Path, rel: str) -> str:
        dst = self.root / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)
        return rel

    def _product(self, scene: str, probe: str, kind: str):
        for p in self.manifest.products:
            if p.scene == scene and p.probe == probe and p.kind == kind and p.path and not p.error:
                return p
        return None

    # -- per scene
    def scene(self, sa: SceneAlignment) -> Scene | None:
        sid = sa.id
        if sa.photo is None:
            self.report.excluded.append(f"{sid}: no photo in the alignment")
            return None
        photo = sa.photo
        src = self._src(photo.path, f"{sid}: photo")
        if sha256_file(src) != photo.sha256:
            raise InputError(f"{src}: photo content differs from the alignment's sha256 (re-run solidkit align)")
        image = read_ldr(src)  # RGB float in [0, 1], whatever the file's bit depth and channels
        K_full = np.asarray(photo.K_full, np.float64)
        small, K_model, box = resize_crop(image, K_full, MODEL_INPUT_SIZE)
        d = f"scenes/{sid}"
        self.root.joinpath(d).mkdir(parents=True, exist_ok=True)
        assert small is not None  # resize_crop returns an image when given one
        write_ldr(self.root / d / "photo.png", small)
        photo_full = self._copy(src, f"{d}/photo_full{src.suffix.lower()}")
        flags = merge_flags(sa.flags)
        if photo.pitch_deg is None or photo.roll_deg is None or photo.pitch_roll_source == "assumed_zero":
            flags.append(FlagCode.PHOTO_PITCH_ROLL_ASSUMED_ZERO.value)

        yaws: dict[str, tuple[float, Candidate, float | None]] = {}
        probes: list[Probe] = []
        camera: CameraCapture | None = None
        for pa in sorted(sa.probes, key=lambda p: (p.role != "camera", p.id)):
            got = self.capture(sid, pa, K_full, K_model, yaws)
            if got is None:
                continue
            if pa.role == "camera":
                camera = cast(CameraCapture, got)
            else:
                probes.append(cast(Probe, got))
        if not probes:
            self.report.excluded.append(f"{sid}: no usable probe")
            return None
        sun = self.sun(sa, yaws)
        self.report.scenes += 1
        self.report.probes += len(probes)
        self.report.hdr_probes += sum(p.hdr is not None for p in probes)
        self.report.sun_found += int(sun.found)
        return Scene(
            id=sid,
            photo=f"{d}/photo.png",
            photo_full=photo_full,
            photo_size=MODEL_INPUT_SIZE,
            photo_full_size=(int(image.shape[1]), int(image.shape[0])),
            crop_box=tuple(int(v) for v in box),
            K=K_model.tolist(),
            K_full=K_full.tolist(),
            K_source=photo.K_source or "unknown",
            pitch_deg=float(photo.pitch_deg or 0.0),
            roll_deg=float(photo.roll_deg or 0.0),
            heading_deg=photo.heading_deg,
            sun=sun,
            camera=camera,
            probes=probes,
            capture=self.photo_capture(photo.sha256, photo.heading_deg),
            flags=flags,
            notes=self._scene_notes(sid),
        )

    def _scene_notes(self, sid: str) -> str | None:
        for s in self.manifest.scenes:
            if s.id == sid:
                return getattr(s, "notes", None)
        return None

    def photo_capture(self, sha: str, heading: float | None) -> PhotoCapture:
        shot = self.shots.get(sha)
        md = shot.metadata if shot else {}
        gps = md.get("gps") or None
        return PhotoCapture(
            original_sha256=sha,
            time_local=md.get("datetime_original"),
            utc_offset=md.get("utc_offset"),
            gps=GPS(lat_deg=gps["lat_deg"], lon_deg=gps["lon_deg"], alt_m=gps.get("alt_m")) if gps else None,
            make=md.get("make"),
            model=md.get("model"),
            exposure=Exposure(exposure_time_s=md.get("exposure_time"), f_number=md.get("f_number"), iso=md.get("iso")),
            focal_length_mm=md.get("focal_length_mm"),
            heading_deg=heading if heading is not None else md.get("heading_deg"),
        )

    # -- per capture
    def capture(
        self,
        sid: str,
        pa: ProbeAlignment,
        K_full: np.ndarray,
        K_model: np.ndarray,
        yaws: dict[str, tuple[float, Candidate, float | None]],
    ) -> Probe | CameraCapture | None:
        key = f"{sid}/{pa.id}"
        auto_yaw = None if pa.yaw_deg is None else Candidate(float(pa.yaw_deg), pa.yaw_source, None, None, (), False)
        yaw = choose(auto_yaw, self.labels.candidate("heading", key, lambda v: float(v["yaw_deg"])))
        if yaw is None:
            self.report.excluded.append(f"{key}: no yaw (not aligned, no heading label)")
            return None
        if pa.yaw_deg is None:
            self.report.excluded.append(
                f"{key}: heading labeled but align wrote no aligned products; re-run solidkit align"
            )
            return None
        delta = wrap_deg(yaw.value - pa.yaw_deg)
        yaws[pa.id] = (float(yaw.value), yaw, delta)
        if abs(delta) > 1e-9:
            self.report.overrides.append(f"{key}: yaw {pa.yaw_deg:.2f} -> {yaw.value:.2f} deg ({yaw.source})")
        rotation = body_to_pano(yaw.value, pa.levelling.pitch_deg, pa.levelling.roll_deg)
        d = f"scenes/{sid}/camera" if pa.role == "camera" else f"scenes/{sid}/probes/{pa.id}"
        try:
            images = self.images(key, pa, d, delta)
        except InputError as exc:
            self.report.excluded.append(f"{key}: {exc}")
            return None
        human_yaw = yaw.from_store and yaw.source in ("annotator", "reviewed")
        flags = merge_flags(
            _drop(pa.flags, ("yaw", "heading", "cue", "residual")) if human_yaw else pa.flags, yaw.flags
        )
        alignment = Alignment(
            yaw_deg=float(yaw.value),
            residual_deg=pa.residual_deg,
            cues={k: Cue(yaw_deg=c.yaw_deg, weight=c.weight, ok=c.ok) for k, c in sorted(pa.cues.items())},
            source=yaw.source,
            annotator=yaw.annotator,
            flags=flags,
        )
        cap = self.probe_capture(sid, pa.id)
        if pa.role == "camera":
            return CameraCapture(id=pa.id, rotation=rotation.tolist(), alignment=alignment, images=images, capture=cap)
        auto_px = None
        if pa.pixel_full is not None:
            source = _LABEL_SOURCE.get(pa.pixel_source or "geometry", "auto")
            if pa.pixel_source == "label":
                lab = self.labels.labels.get(("probe_pixel", key))
                source = lab.source if lab is not None else "annotator"
            auto_px = Candidate((float(pa.pixel_full[0]), float(pa.pixel_full[1])), source)
        px = choose(auto_px, self.labels.candidate("probe_pixel", key, lambda v: (float(v["x"]), float(v["y"]))))
        if px is None:
            self.report.excluded.append(f"{key}: no photo pixel (field notes or probe_pixel label)")
            return None
        pixel = pixel_to_model(px.value, K_full, K_model)
        return Probe(
            id=pa.id,
            pixel=pixel,
            pixel_full=px.value,
            pixel_source=px.source,
            pixel_annotator=px.annotator,
            ldr=images.ldr,
            hdr=images.hdr,
            rotation=rotation.tolist(),
            alignment=alignment,
            images=images,
            capture=cap,
            flags=merge_flags(
                _drop(flags, ("pixel",)) if px.from_store and px.source in ("annotator", "reviewed") else flags,
                px.flags,
            ),
            note=self._probe_note(sid, pa.id),
        )

    def _probe_note(self, sid: str, pid: str) -> str | None:
        for s in self.manifest.scenes:
            if s.id == sid:
                for p in s.probes:
                    if p.id == pid:
                        return getattr(p, "note", None)
        return None

    def images(self, key: str, pa: ProbeAlignment, d: str, delta: float) -> ProbeImages:
        prod = pa.products
        out: dict[str, str | None] = {}
        R = level_to_pano(delta) if abs(delta) > 1e-9 else None
        for name, rel, kind in (
            ("ldr", prod.ldr_256, "ldr"),
            ("ldr_full", prod.ldr_full, "ldr"),
            ("hdr", prod.hdr_256, "hdr"),
            ("hdr_full", prod.hdr_full, "hdr"),
            ("saturation", prod.saturation_256, "mask"),
            ("saturation_full", prod.saturation_full, "mask"),
        ):
            if rel is None:
                out[name] = None
                continue
            src = self._src(rel, f"{key}: aligned {name}")
            dst = f"{d}/{name}{'.exr' if kind == 'hdr' else '.png'}"
            if R is None and src.suffix.lower() == Path(dst).suffix:
                out[name] = self._copy(src, dst)
            elif kind == "hdr":
                img, meta = read_exr(src)
                meta.pop("header", None)
                write_exr(self.root / dst, rotate(img, R, "linear") if R is not None else img, meta)
                out[name] = dst
            else:
                img = imread(src)
                interp = "nearest" if kind == "mask" else "linear"
                out[name] = dst
                self.root.joinpath(dst).parent.mkdir(parents=True, exist_ok=True)
                rot = rotate(img.astype(np.float32), R, interp) if R is not None else img.astype(np.float32)
                _write_u8(self.root / dst, rot)
        if out["ldr"] is None or out["ldr_full"] is None:
            missing = "ldr_256" if out["ldr"] is None else "ldr_full"
            raise InputError(f"align wrote no aligned {missing} product")
        ldr = imread(self.root / out["ldr"])
        if ldr.shape[:2] != (PROBE_SIZE[1], PROBE_SIZE[0]):
            raise InputError(
                f"aligned ldr_256 is {ldr.shape[1]}x{ldr.shape[0]}, expected {PROBE_SIZE[0]}x{PROBE_SIZE[1]}"
            )
        full = imread(self.root / out["ldr_full"])
        for name, size in (("saturation", ldr), ("saturation_full", full)):
            if out[name] is None:  # align gave none: clipped LDR pixels
                mask = size.reshape(size.shape[0], size.shape[1], -1)[..., :3].max(axis=-1) >= SATURATION_LEVEL
                out[name] = f"{d}/{name}.png"
                _write_u8(self.root / cast(str, out[name]), mask.astype(np.float32) * 255.0)
        sat = imread(self.root / cast(str, out["saturation"]))
        sat = sat if sat.ndim == 2 else sat[..., 0]
        return ProbeImages(
            ldr=out["ldr"],
            ldr_full=out["ldr_full"],
            hdr=out["hdr"],
            hdr_full=out["hdr_full"],
            saturation=out["saturation"],
            saturation_full=out["saturation_full"],
            ldr_full_size=(int(full.shape[1]), int(full.shape[0])),
            saturated_fraction=_saturated_fraction(sat),
        )

    def probe_capture(self, sid: str, pid: str) -> ProbeCapture:
        probe = None
        for s in self.manifest.scenes:
            if s.id == sid:
                probe = next((p for p in s.probes if p.id == pid), None)
        if probe is None:
            return ProbeCapture()
        first = self.shots[probe.shots[0]].metadata if probe.shots and probe.shots[0] in self.shots else {}
        bracket = probe.brackets[0] if probe.brackets else None
        hdr = self._product(sid, pid, "hdr")
        sun = self._product(sid, pid, "sun_frame")
        normal = normal_shot_of(self.manifest, probe)
        return ProbeCapture(
            time_local=first.get("datetime_original"),
            camera_model=first.get("model"),
            shots=list(probe.shots),
            bracket_exposures_s=[float(t) for t in (bracket.exposure_times if bracket else []) if t is not None],
            bracket_f_number=hdr.f_number if hdr else None,
            bracket_iso=hdr.iso if hdr else None,
            sun_frame_exposure=Exposure(exposure_time_s=sun.exposure_time, f_number=sun.f_number, iso=sun.iso)
            if sun
            else None,
            ldr_exposure=None
            if normal is None
            else Exposure(
                exposure_time_s=normal.metadata.get("exposure_time"),
                f_number=normal.metadata.get("f_number"),
                iso=normal.metadata.get("iso"),
            ),
            recorded_pitch_deg=first.get("pitch_deg"),
            recorded_roll_deg=first.get("roll_deg"),
        )

    # -- the sun
    def sun(self, sa: SceneAlignment, yaws: dict[str, tuple[float, Candidate, float | None]]) -> Sun:
        s = sa.sun
        auto = Candidate(
            (s.found, s.azimuth_deg, s.elevation_deg, s.uncertainty_deg), s.source, None, None, tuple(s.flags)
        )
        label = self.labels.candidate(
            "sun_scene",
            sa.id,
            lambda v: (bool(v["found"]), v.get("azimuth_deg"), v.get("elevation_deg"), v.get("uncertainty_deg")),
        )
        win = choose(auto, label)
        assert win is not None  # auto is always a candidate
        found, az, el, unc = win.value
        if found and (az is None or el is None):
            raise InputError(f"{sa.id}: sun found without azimuth/elevation ({win.source})")
        direction = None
        if found:
            direction = [float(v) for v in direction_from_angles(math.radians(az), math.radians(el))]
        # the low-exposure panorama: the capture whose sun entered the consensus best (camera first)
        found_caps = sorted(
            (c for c in s.captures if c.found and c.probe in yaws),
            key=lambda c: (
                c.probe != sa.camera_probe,
                c.uncertainty_deg if c.uncertainty_deg is not None else 1e9,
                c.probe,
            ),
        )
        pick = found_caps[0].probe if found_caps else (sa.camera_probe if sa.camera_probe in yaws else None)
        panorama = exposure = None
        flags = (
            list(win.flags)
            if win.from_store and win.source != "auto"
            else merge_flags(auto.flags, label.flags if label else ())
        )
        if pick is not None:
            prod = self._product(sa.id, pick, "sun_frame")
            if prod is None:
                flags.append(FlagCode.NO_SUN_FRAME.value)
            else:
                pano = read_ldr(self._src(prod.path, f"{sa.id}/{pick}: sun frame"))
                if pano.shape[1] != 2 * pano.shape[0]:
                    flags.append(FlagCode.SUN_FRAME_NOT_A_PANORAMA.value)
                else:
                    panorama = f"scenes/{sa.id}/sun_panorama.png"
                    write_ldr(self.root / panorama, rotate(pano, level_to_pano(yaws[pick][0]), "linear"))
                    exposure = Exposure(exposure_time_s=prod.exposure_time, f_number=prod.f_number, iso=prod.iso)
        return Sun(
            found=bool(found),
            azimuth_deg=float(az) if found else None,
            elevation_deg=float(el) if found else None,
            uncertainty_deg=None if unc is None else float(unc),
            direction=direction,
            source=win.source,
            annotator=win.annotator,
            label_version=win.label_version,
            flags=flags,
            panorama=panorama,
            panorama_capture=pick if panorama else None,
            panorama_exposure=exposure,
        )

    # -- profiles
    def profiles(self) -> list[ProfileRef]:
        """Every calibration profile the campaign's products were made with, copied by content hash."""
        refs = [
            self._profile("response", self.manifest.response),
            self._profile("lens", self.manifest.lens_profile),
            self._profile("vignetting", self.manifest.vignetting),
        ]
        if self.manifest.lens_profile is None:  # the camera models' shipped profiles, as the products record them
            names = sorted({str(p.stats["profile"]) for p in self.manifest.products if p.stats.get("profile")})
            refs += [self._profile("lens", {"kind": "shipped", "name": n}) for n in names]
        return [r for r in refs if r is not None]

    def _profile(self, role: str, entry: dict[str, Any] | None) -> ProfileRef | None:
        if not entry:
            return None
        kind = entry.get("kind")
        if kind == "file":
            src = self._src(entry.get("path"), f"{role} profile")
            sha = sha256_file(src)
            return ProfileRef(
                role=role,
                kind="file",
                name=Path(entry.get("path", "")).name,
                sha256=sha,
                path=self._copy(src, f"profiles/{sha}{src.suffix}"),
            )
        if kind == "shipped":
            from importlib import resources

            name = str(entry.get("name"))
            res = resources.files("solidkit.camera").joinpath("profiles", f"{name}.json")
            if not res.is_file():
                return ProfileRef(role=role, kind="shipped", name=name, sha256=entry.get("sha256"))
            data = res.read_bytes()
            sha = hashlib.sha256(data).hexdigest()
            rel = f"profiles/{sha}.json"
            (self.root / "profiles").mkdir(exist_ok=True)
            (self.root / rel).write_bytes(data)
            return ProfileRef(role=role, kind="shipped", name=name, sha256=sha, path=rel)
        return ProfileRef(role=role, kind="builtin", name=str(kind))


def _write_u8(path: Path, image: np.ndarray) -> None:
    """8-bit PNG of an OpenCV-ordered (BGR / grey) image given as float 0-255."""
    data = np.clip(np.round(np.asarray(image, np.float32)), 0, 255).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), data):
            raise InputError(f"{path}: cannot write PNG")


def _files(root: Path) -> dict[str, FileEntry]:
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.name != MANIFEST_FILE:
            out[p.relative_to(root).as_posix()] = FileEntry(sha256=sha256_file(p), bytes=p.stat().st_size)
    return out


# --------------------------------------------------------------------------- output folder
def _check_out(out: Path, campaign: Path) -> None:
    """Refuse an OUT that is not absent, empty or a previous test set; or that overlaps the campaign."""
    o, c = out.resolve(), campaign.resolve()
    if o == c or c in o.parents or o in c.parents:
        raise InputError(f"{out}: the test set folder must be outside the campaign {campaign} (and not contain it)")
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        m = out / MANIFEST_FILE
        try:
            fmt = json.loads(m.read_text(encoding="utf-8")).get("format") if m.is_file() else None
        except (OSError, ValueError, AttributeError):
            fmt = None
        if fmt != FORMAT:
            raise InputError(
                f"{out}: exists and is not a solidkit test set (no {MANIFEST_FILE}); refusing to overwrite it"
            )


def load_testset(root: str | os.PathLike) -> TestSet:
    """Read and validate ``ROOT/testset.json``; one-line :class:`InputError` otherwise."""
    path = Path(root) / MANIFEST_FILE
    if not path.is_file():
        raise InputError(f"{root}: not a test set (no {MANIFEST_FILE})")
    data = read_json_object(path, InputError, "test set manifest", finite=True)
    return validate_versioned(
        path,
        data,
        TestSet,
        kind_key="format",
        kind=FORMAT,
        version_key="version",
        version=SCHEMA_VERSION,
        what="test set manifest",
    )


def build_testset(
    campaign: str | os.PathLike,
    out: str | os.PathLike,
    *,
    log: Callable[[str], None] | None = None,
    wait: bool = False,
) -> BuildReport:
    """Build the test set of ``campaign`` into ``out`` (see the module docstring); returns a :class:`BuildReport`.

    Reads the campaign under its lock (:func:`solidkit.capture.lock.campaign_lock`: refused while an
    ingest, align or label sun runs, unless ``wait``) and refuses an alignment older than the
    campaign's manifest (an ingest ran since) or one that lacks some of its scenes.
    """
    campaign, out = Path(campaign), Path(out)
    if not (campaign / "manifest.json").is_file():
        raise InputError(f"{campaign}: not a campaign (no manifest.json; run solidkit ingest first)")
    _check_out(out, campaign)
    with campaign_lock(campaign, "testset build", wait=wait, log=log):
        manifest = load_manifest(campaign)
        alignment = load_alignment(campaign)
        manifest_sha = sha256_file(campaign / "manifest.json")
        _check_alignment(campaign, manifest, alignment, manifest_sha)
        report = BuildReport(out=out)
        out.parent.mkdir(parents=True, exist_ok=True)
        with _exclusive(out):
            return _build(campaign, out, manifest, alignment, manifest_sha, report, log)


def _check_alignment(campaign: Path, manifest: Manifest, alignment: CampaignAlignment, manifest_sha: str) -> None:
    """Refuse an alignment older than the manifest (its products) or missing some of its scenes."""
    stale = (
        alignment.manifest_sha256 != manifest_sha
        if alignment.manifest_sha256
        else (campaign / "align" / "alignment.json").stat().st_mtime_ns
        < (campaign / "manifest.json").stat().st_mtime_ns
    )
    if stale:
        raise InputError(
            f"{campaign}: the alignment is older than the campaign's manifest (it was computed from another one: "
            "an ingest changed products or scenes since); re-run solidkit align"
        )
    aligned = {sa.id for sa in alignment.scenes}
    missing = [sc.id for sc in manifest.scenes if sc.id not in aligned]
    if missing:
        raise InputError(
            f"{campaign}: the alignment lacks {len(missing)} of the campaign's {len(manifest.scenes)} scenes "
            f"({', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}: an align was interrupted or ran with "
            "--scene); re-run solidkit align"
        )


@contextlib.contextmanager
def _exclusive(out: Path) -> Iterator[None]:
    """One build per output folder at a time: an flock on ``.<out>.lock`` beside it (kept, so that
    every build locks the same inode); a second concurrent build is refused."""
    lock = out.parent / f".{out.name}.lock"
    with open(lock, "a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"{out}: another testset build is writing it") from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _build(
    campaign: Path,
    out: Path,
    manifest: Manifest,
    alignment: CampaignAlignment,
    manifest_sha: str,
    report: BuildReport,
    log: Callable[[str], None] | None,
) -> BuildReport:
    for stale in out.parent.glob(f".{out.name}.build-*"):  # left by a killed build
        shutil.rmtree(stale, ignore_errors=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.build-", dir=out.parent))
    try:
        b = _Builder(campaign, staging, manifest, alignment, report)
        scenes = []
        for sa in sorted(alignment.scenes, key=lambda s: s.id):
            if log:
                log(f"scene {sa.id}")
            sc = b.scene(sa)
            if sc is not None:
                scenes.append(sc)
        if not scenes:
            raise InputError(f"{campaign}: no usable scene; " + "; ".join(report.excluded[:5]))
        profiles = b.profiles()
        labels_sha = b.labels.digest()
        report.labels_used = len(b.labels.used)
        ts = TestSet(
            conventions_version=CONVENTIONS_VERSION,
            solidkit_version=__version__,
            inputs=Inputs(
                campaign=campaign.resolve().name,
                manifest_sha256=manifest_sha,
                alignment_sha256=sha256_file(campaign / "align" / "alignment.json"),
                labels_sha256=labels_sha,
                labels_used=len(b.labels.used),
            ),
            profiles=profiles,
            scenes=scenes,
            files=_files(staging),
        )
        ts.dataset_version = content_version(ts)
        report.dataset_version = ts.dataset_version
        (staging / MANIFEST_FILE).write_text(canonical_json(ts.model_dump(mode="json")), encoding="utf-8")
        old = out / MANIFEST_FILE
        if old.is_file() and old.read_bytes() == (staging / MANIFEST_FILE).read_bytes() and _same_files(out, ts):
            report.changed = False
            return report
        _swap(staging, out)
        return report
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)


def _same_files(root: Path, ts: TestSet) -> bool:
    """True when ``root`` holds exactly the files of ``ts`` with their checksums."""
    try:
        return _files(root) == ts.files
    except OSError:
        return False


def _swap(staging: Path, out: Path) -> None:
    """Put ``staging`` at ``out``: rename the old folder aside, rename the new one in, delete the old."""
    os.chmod(staging, 0o755)
    if out.exists():
        trash = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.rename(out, trash / "x")
        os.rename(staging, out)
        shutil.rmtree(trash, ignore_errors=True)
    else:
        os.rename(staging, out)
