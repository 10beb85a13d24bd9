"""``solidkit align CAMPAIGN``: sun labels, yaws, probe pixels and aligned products for every scene.

Order per scene (truth is never read; only the manifest, the originals, ingest's products and the
label store):

1. The photo: its intrinsics from EXIF (:func:`solidkit.calibration.camera.intrinsics_from_exif`),
   heading, time and GPS.
2. Features (:mod:`solidkit.align.features`) of the photo and of every capture's level panorama
   (the merged HDR, else the normal shot), cached under ``CAMPAIGN/align/cache`` by input hash;
   each capture's levelling refined by the residual tilt of its vertical edges
   (:func:`solidkit.envmap.tilt.residual_tilt`, weighted against the metadata's gravity).
3. Yaw cues without the sun: photo <-> camera position (rotation; it also refines the photo's
   focal length and measures its pitch and roll), capture <-> camera position (level relative
   pose), compass.
4. The sun (:func:`solidkit.align.sun.scene_sun`) with the feature yaws (compass-only captures
   are tested on elevation: a compass may be 90° off); the sun's motion between the captures'
   times applied or not as the images say (``AlignSettings.sun_motion``); then the ``sun`` cue of
   every capture that saw it (leave-one-out: the scene's sun from the *other* captures).
   Captures left with the compass alone get ``features_via_<id>`` cues through the other captures,
   then ``manhattan`` cues (:mod:`solidkit.align.manhattan`), then a ``linked`` cue
   (:mod:`solidkit.align.links`): features between them and every other capture, and their skies
   (:mod:`solidkit.align.sky`), tie them to captures of known yaw or, failing that, to each
   other's compasses (flagged ``yaw_from_compasses``; ``yaw_from_sky`` when only skies link them).
   The final consensus per capture (:func:`~solidkit.align.heading.fuse_cues`); a human ``heading``
   label overrides it; human ``sun`` labels replace the automatic choice of their capture.
5. Probe pixels (field notes, else a human label, else the geometry) checked against the
   geometry: the direction from the camera position to the probe capture (relative pose),
   projected into the photo.
6. Products (:mod:`solidkit.align.products`), ``align/alignment.json`` (C3), auto labels in the
   label store (C2, ``source="auto"``, annotator ``align``), the report (:mod:`solidkit.align.report`).

Re-runs are idempotent: unchanged inputs reuse cached features and existing products (recipe
hash), and the label store ignores identical puts. A scene whose alignment raises is recorded
flagged ``align_failed`` with the error (:func:`failed_scene`), and the other scenes are kept.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, cast

import numpy as np

from solidkit import __version__
from solidkit.align.captures import (
    Capture,
    camera_probe_of,
    captures_of,
    exposure_stops,
    levelling_of,
    load_normal_panorama,
    photo_shot_of,
    read_hdr,
    read_sun_frame,
)
from solidkit.align.ephemeris import DRIFT_HOURS, at_photo_time, capture_place, capture_time, ephemeris_for, hours_apart
from solidkit.align.features import Features, panorama_features, photo_features, rays_from_pixels
from solidkit.align.heading import feature_cue, fuse_cues, match_photo
from solidkit.align.links import GROUND, Link, solve_links
from solidkit.align.manhattan import line_normals, photo_line_normals, vanishing_azimuth
from solidkit.align.products import write_products
from solidkit.align.report import write_report
from solidkit.align.schema import (
    ALIGNMENT_FILE,
    CampaignAlignment,
    CaptureSun,
    Cue,
    Ephemeris,
    Levelling,
    PhotoInfo,
    ProbeAlignment,
    SceneAlignment,
    SceneSun,
    body_to_pano,
    load_alignment,
    photo_azimuth_from_solar,
    save_alignment,
    solar_azimuth_from_photo,
    wrap_deg,
)
from solidkit.align.sky import relative_sky_yaw, sky_layer, without_sun_drift
from solidkit.align.sun import Blob, CaptureSunInput, SunSettings, choose_sun, find_candidates, sky_fraction
from solidkit.calibration.camera import IntrinsicsError, intrinsics_from_exif, intrinsics_from_fov
from solidkit.camera.metadata import CaptureMetadata
from solidkit.capture.lock import campaign_lock
from solidkit.capture.manifest import Manifest, Scene, load_manifest
from solidkit.envmap.coords import (
    angles_from_direction,
    angular_distance,
    direction_from_angles,
    rotation_from_ypr,
    ypr_from_rotation,
)
from solidkit.envmap.io import read_ldr, srgb_decode
from solidkit.envmap.resample import rotate
from solidkit.envmap.tilt import TiltEstimate, residual_tilt
from solidkit.errors import InputError, SolidkitError
from solidkit.flags import Flag, FlagCode, flag_codes
from solidkit.fsutil import atomic_path, sha256_file
from solidkit.labeling.store import LabelStore
from solidkit.threads import deterministic

__all__ = ["AlignSettings", "align_campaign", "align_scene"]

ANNOTATOR = "align"


@dataclass(frozen=True)
class AlignSettings:
    """Settings of a run (recorded in ``alignment.json``)."""

    sun: SunSettings = field(default_factory=SunSettings)
    photo_compass_sigma_deg: float = 5.0
    feature_fov_deg: float = 75.0
    feature_pitches_deg: tuple[float, ...] = (0.0, 45.0, -45.0)
    photo_scale: float | None = None
    refine_levelling: bool = True
    pixel_tolerance_deg: float = 5.0
    pixel_n_sigma: float = 4.0
    min_pixel_check_inliers: int = 20
    manhattan: bool = True
    manhattan_max_ambiguity: float = 0.85
    manhattan_model_sigma_deg: float = 0.5
    links: bool = True
    sky: bool = True
    sky_correlation_px: float = 18.0
    sky_min_delta_chi2: float = 9.0
    sky_min_overlap: float = 0.005
    min_translation_support: int = 8
    refine_focal: bool = True
    min_pose_inliers: int = 15
    max_baseline_elevation_deg: float | None = 60.0
    match_ratio: float = 0.85
    sun_motion: str = "auto"
    focal_tolerance: float = 0.02
    products: bool = True
    probe_height: int = 128

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["feature_pitches_deg"] = list(self.feature_pitches_deg)
        return d


# --------------------------------------------------------------------------- features (cached)
def _cache_key(*parts: Any) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:24]


def _cached(campaign: Path, key: str, make: Callable[[], Features]) -> Features:
    path = campaign / "align" / "cache" / f"features-{key}.npz"
    if path.is_file():
        try:
            with np.load(path) as z:
                return Features(z["directions"], z["descriptors"], z["pixels"], z["sizes"])
        except (OSError, ValueError, KeyError):
            path.unlink(missing_ok=True)
    f = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez_compressed(tmp, directions=f.directions, descriptors=f.descriptors, pixels=f.pixels, sizes=f.sizes)
    return f


def _feature_panorama(
    campaign: Path, manifest: Manifest, cap: Capture
) -> tuple[np.ndarray | None, bool, str, list[str]]:
    """(level panorama for features, is_linear, description, input hashes)."""
    if cap.hdr_path:  # keyed by the product's content: a rebuilt or replaced product is new input
        return read_hdr(campaign, cap.hdr_path), True, cap.hdr_path, [sha256_file(campaign / cap.hdr_path)]
    if cap.normal is not None:
        return load_normal_panorama(campaign, manifest, cap.normal), False, cap.normal.original, [cap.normal.sha256]
    return None, False, "", []


# --------------------------------------------------------------------------- photo
def _photo_info(campaign: Path, manifest: Manifest, scene: Scene) -> tuple[PhotoInfo | None, list[str]]:
    flags: list[str] = []
    shot = photo_shot_of(manifest, scene)
    if shot is None:
        return None, [str(Flag(FlagCode.NO_PHOTO, "the scene has no photo"))]
    meta = CaptureMetadata.model_validate(shot.metadata)
    try:
        K, source = intrinsics_from_exif(meta)
    except IntrinsicsError as exc:
        K, source = intrinsics_from_fov(math.radians(60.0), meta.width, meta.height), "assumed-hfov-60"
        flags.append(str(Flag(FlagCode.NO_INTRINSICS, f"{exc}; a 60 deg field of view is assumed")))
    heading = getattr(scene, "photo_heading_deg", None)
    if heading is None:
        heading = (shot.metadata.get("gps") or {}).get("img_direction_deg")
    pitch, roll = getattr(scene, "photo_pitch_deg", None), getattr(scene, "photo_roll_deg", None)
    when, _ = capture_time(shot.metadata)
    info = PhotoInfo(
        path=shot.original,
        sha256=shot.sha256,
        size=[meta.width, meta.height],
        K_full=np.asarray(K).tolist(),
        K_source=source,
        pitch_deg=pitch,
        roll_deg=roll,
        heading_deg=heading,
        pitch_roll_source="exif" if pitch is not None and roll is not None else "",
        time=None if when is None else when.isoformat(),
    )
    if heading is None:
        flags.append(
            str(
                Flag(
                    FlagCode.NO_PHOTO_HEADING,
                    "no compass heading for the photo (GPSImgDirection); world azimuths unknown",
                )
            )
        )
    return info, flags


@dataclass(frozen=True)
class ScenePhoto:
    """Step 1 of :func:`align_scene`: the scene's photo (``info``; None: no photo) with its EXIF intrinsics
    and compass heading, the ephemeris at its time and place, the camera-position capture's id, and the
    scene's flags so far."""

    info: PhotoInfo | None
    ephemeris: Ephemeris | None
    place: tuple[float, float, float | None] | None
    camera_probe: str | None
    flags: list[str]

    @property
    def heading_deg(self) -> float | None:
        """The photo's compass heading (clockwise from true north), degrees."""
        return self.info.heading_deg if self.info is not None else None


def scene_photo(campaign: Path, manifest: Manifest, scene: Scene) -> ScenePhoto:
    """Step 1: the photo of ``scene`` (:class:`ScenePhoto`)."""
    info, flags = _photo_info(campaign, manifest, scene)
    cam_id = camera_probe_of(scene)
    if cam_id is None:
        flags.append(
            str(Flag(FlagCode.NO_CAMERA_POSITION, "no capture is marked as taken at the photo camera's position"))
        )
    shot = photo_shot_of(manifest, scene)
    place = capture_place(shot.metadata) if shot is not None else None
    eph = ephemeris_for(shot.metadata) if shot is not None else None
    if shot is not None:
        flags += photo_clock_mismatch(shot)
    return ScenePhoto(info, eph, place, cam_id, flags)


def photo_clock_mismatch(shot: Any) -> list[str]:
    """The scene's ``clock_mismatch`` flag where the photo's clock disagrees with its own GPS time
    (:func:`solidkit.camera.metadata.gps_clock_warning`, a metadata warning of the photo shot): the one ingest
    lists among the scene's warnings, ``clock_mismatch: photo <card path>: <detail>``."""
    name = min(shot.sources, key=lambda r: (r.card, r.path)).path if shot.sources else Path(shot.original).name
    return [
        str(Flag(FlagCode.CLOCK_MISMATCH, f"photo {name}: {Flag.parse(w).detail}"))
        for w in shot.metadata.get("warnings", [])
        if Flag.parse(w).code == FlagCode.CLOCK_MISMATCH.value
    ]


# --------------------------------------------------------------------------- captures
@dataclass(frozen=True, eq=False)
class CaptureView:
    """Step 2: one capture before any yaw: its metadata levelling (degrees) and compass heading, its
    ephemeris (at the photo's place), its features in the refined level frame, and its normal-exposure
    panorama (linear; ``linear``: from an HDR product, else a decoded LDR shot clipped at 1).

    ``C``: the product's level frame -> the refined level frame ``(3, 3)`` (the residual ``tilt`` of its
    vertical edges weighted against the metadata's gravity).
    """

    cap: Capture
    pitch: float = 0.0
    roll: float = 0.0
    heading: float | None = None
    ephemeris: Ephemeris | None = None
    features: Features | None = None
    normal_lin: np.ndarray | None = None
    linear: bool = False
    C: np.ndarray = field(default_factory=lambda: np.eye(3))
    tilt: TiltEstimate | None = None
    flags: tuple[str, ...] = ()

    @property
    def id(self) -> str:
        return self.cap.id

    @property
    def pano_height(self) -> int:
        """Height of the normal panorama (pixels; 960 without one)."""
        return int(self.normal_lin.shape[0]) if self.normal_lin is not None else 960


def _refine_levelling(pano: np.ndarray, s: AlignSettings) -> tuple[np.ndarray, TiltEstimate | None]:
    """The correction ``C`` of the metadata levelling by the panorama's residual tilt (vertical edges),
    weighting both by their uncertainties (small angles: each tilt component is a weighted mean of the
    metadata's 0 and the edges' estimate), and the tilt estimate (None: none could be made)."""
    try:
        est = residual_tilt(pano)
    except SolidkitError:
        return np.eye(3), None
    if not est.reliable:
        return np.eye(3), est
    w = s.sun.level_sigma_deg**2 / (s.sun.level_sigma_deg**2 + max(est.uncertainty_deg, 0.05) ** 2)
    return np.asarray(rotation_from_ypr(0.0, math.radians(w * est.pitch_deg), math.radians(w * est.roll_deg))), est


def capture_view(
    campaign: Path,
    manifest: Manifest,
    scene_id: str,
    cap: Capture,
    s: AlignSettings,
    photo_place: tuple[float, float, float | None] | None,
    log: Callable[[str], None] = lambda s: None,
) -> CaptureView:
    """Step 2: the :class:`CaptureView` of ``cap`` (features cached under ``CAMPAIGN/align/cache``)."""
    flags: list[str] = []
    pitch, roll, heading, eph = 0.0, 0.0, None, None
    ref = cap.normal
    if ref is not None:
        pitch, roll, _ = levelling_of(ref)
        heading = ref.metadata.get("heading_deg")
        eph = ephemeris_for(ref.metadata, photo_place)
        substituted = exposure_substitute(ref)
        if substituted:
            flags.append(substituted)
    else:
        flags.append(str(Flag(FlagCode.NO_NORMAL_SHOT, "no single exposure to make the LDR probe from")))
    pano, linear, src, inputs = _feature_panorama(campaign, manifest, cap)
    if pano is None:
        flags.append(str(Flag(FlagCode.NO_PANORAMA, "neither an HDR product nor a normal shot")))
        return CaptureView(cap, pitch, roll, heading, eph, flags=tuple(flags))
    key = _cache_key("pano", inputs, src, s.feature_fov_deg, list(s.feature_pitches_deg), linear, 2)
    features = _cached(
        campaign,
        key,
        lambda: panorama_features(pano, fov_deg=s.feature_fov_deg, pitches_deg=s.feature_pitches_deg, linear=linear),
    )
    normal_lin = pano if linear else srgb_decode(pano.astype(np.float32) / 255.0)
    C, tilt = np.eye(3), None
    if s.refine_levelling:
        C, tilt = _refine_levelling(pano, s)
        features = Features(features.directions @ C.T, features.descriptors, features.pixels, features.sizes)
    how = "" if tilt is None else "reliable" if tilt.reliable else "unreliable"
    log(
        f"{scene_id}/{cap.id}: {len(features)} features"
        + ("" if tilt is None else f", residual tilt {tilt.tilt_deg:.2f} deg ({how})")
    )
    return CaptureView(cap, pitch, roll, heading, eph, features, normal_lin, linear, C, tilt, tuple(flags))


def exposure_substitute(shot: Any, max_stops: float = 0.25) -> str | None:
    """The ``normal_exposure_substituted`` flag of a capture whose LDR probe comes from ``shot`` when its exposure
    is more than ``max_stops`` from the protocol's 1/2500 s (a bracket missing that shot), else None."""
    stops = exposure_stops(shot)
    if abs(stops) <= max_stops:
        return None
    t = float(shot.metadata["exposure_time"])
    return str(
        Flag(
            FlagCode.NORMAL_EXPOSURE_SUBSTITUTED,
            f"the LDR probe is made from the {_exposure_text(t)} shot: the protocol's 1/2500 s is missing "
            f"({2.0**stops:.1f}x {'brighter' if stops > 0 else 'darker'})",
        )
    )


def _exposure_text(t: float) -> str:
    """An exposure time as a camera shows it: ``1/640 s``, ``2 s``."""
    return f"1/{1.0 / t:.0f} s" if t < 1.0 else f"{t:g} s"


def far_from_photo(photo_ephemeris: Ephemeris | None, views: list[CaptureView]) -> list[str]:
    """The captures taken more than :data:`DRIFT_HOURS` from the photo (ids, in ``views`` order)."""
    if photo_ephemeris is None:
        return []
    return [v.id for v in views if v.ephemeris is not None and hours_apart(photo_ephemeris, v.ephemeris) > DRIFT_HOURS]


def clock_mismatch(photo_ephemeris: Ephemeris | None, views: list[CaptureView]) -> list[str]:
    """The scene's ``clock_mismatch`` flag: captures taken more than :data:`DRIFT_HOURS` from the photo."""
    far = far_from_photo(photo_ephemeris, views)
    if not far:
        return []
    return [
        str(
            Flag(
                FlagCode.CLOCK_MISMATCH,
                f"{', '.join(far)} taken more than an hour from the photo "
                "(camera clocks or UTC offsets disagree); no sun drift correction there",
            )
        )
    ]


# --------------------------------------------------------------------------- yaw cues without the sun
@dataclass(frozen=True)
class PhotoStage:
    """Step 3: the photo matched to the camera-position capture: the photo with its refined intrinsics and
    measured pitch/roll, the camera capture's ``photo_features`` cue (None: no match tried) and flags."""

    photo: PhotoInfo | None
    cue: Cue | None
    flags: list[str]


def photo_stage(campaign: Path, photo: PhotoInfo | None, cam: CaptureView | None, s: AlignSettings) -> PhotoStage:
    """Step 3: the rotation between the photo and the camera-position panorama (:func:`match_photo`), which
    refines the photo's focal length and measures its pitch and roll; pitch and roll still unknown are
    assumed zero (flagged)."""
    flags: list[str] = []
    cue = None
    if photo is not None:
        photo = photo.model_copy()
    if cam is not None and cam.features is not None and photo is not None:
        img = read_ldr(campaign / photo.path)
        K = np.asarray(photo.K_full)
        # SIFT at the panorama's angular resolution: photo pixels per radian -> panorama's (H / pi)
        scale = s.photo_scale or min(1.0, (cam.pano_height / math.pi) / K[0, 0] * 1.1)
        pf = _cached(
            campaign,
            _cache_key("photo", photo.sha256, photo.K_full, scale, 2),
            lambda: photo_features(img, K, scale=scale),
        )
        pm, detail = match_photo(pf, cam.features, K=K, refine_f=s.refine_focal, ratio=s.match_ratio)
        if pm is not None and pm.focal_scale != 1.0:
            Kr = K.copy()
            Kr[0, 0] *= pm.focal_scale
            Kr[1, 1] *= pm.focal_scale
            if abs(pm.focal_scale - 1.0) > s.focal_tolerance:
                flags.append(
                    str(
                        Flag(
                            FlagCode.FOCAL_REFINED,
                            f"the EXIF focal length was {100 * (pm.focal_scale - 1):+.1f}% off "
                            f"({photo.K_source}); K refined from the camera-position panorama",
                        )
                    )
                )
            photo.K_full, photo.K_source = Kr.tolist(), f"{photo.K_source}+features"
        if pm is not None:
            cue = Cue(
                yaw_deg=pm.yaw_deg,
                sigma_deg=pm.sigma_deg,
                ok=True,
                detail=detail + f"; photo pitch {pm.pitch_deg:+.2f}, roll {pm.roll_deg:+.2f} deg",
            )
            if photo.pitch_deg is not None and photo.roll_deg is not None:
                d = max(abs(photo.pitch_deg - pm.pitch_deg), abs(photo.roll_deg - pm.roll_deg))
                if d > 1.0:
                    flags.append(
                        str(
                            Flag(
                                FlagCode.PHOTO_POSE_DISAGREES,
                                f"recorded pitch/roll {photo.pitch_deg:+.2f}/{photo.roll_deg:+.2f},"
                                f" features {pm.pitch_deg:+.2f}/{pm.roll_deg:+.2f} deg",
                            )
                        )
                    )
            if photo.pitch_deg is None or photo.roll_deg is None or pm.n_inliers >= s.min_pose_inliers:
                # the rotation to a levelled panorama measures the photo's pitch and roll better than a bubble level
                photo.pitch_deg, photo.roll_deg = pm.pitch_deg, pm.roll_deg
                photo.pitch_roll_source = "features"
        else:
            cue = Cue(yaw_deg=None, ok=False, detail=detail)
            flags.append(str(Flag(FlagCode.PHOTO_MATCH_FAILED, detail)))
    if photo is not None and (photo.pitch_deg is None or photo.roll_deg is None):
        photo.pitch_deg, photo.roll_deg, photo.pitch_roll_source = 0.0, 0.0, "assumed_zero"
        flags.append(str(Flag(FlagCode.PHOTO_POSE_UNKNOWN, "pitch and roll assumed zero")))
    return PhotoStage(photo, cue, flags)


def compass_cue(view: CaptureView, photo_heading_deg: float | None, s: AlignSettings) -> Cue:
    """The ``compass`` cue: ``yaw = heading - photo heading`` (heading convention, :mod:`solidkit.align.schema`)."""
    if view.heading is not None and photo_heading_deg is not None:
        return Cue(
            yaw_deg=wrap_deg(float(view.heading) - float(photo_heading_deg)),
            sigma_deg=s.sun.compass_sigma_deg,
            ok=True,
            detail=f"Theta heading {float(view.heading):.1f} deg - photo heading {float(photo_heading_deg):.1f} deg",
        )
    return Cue(yaw_deg=None, ok=False, detail="no compass heading")


@dataclass(frozen=True)
class CameraFeatures:
    """Step 4: the camera-position capture's yaw before the sun (its cues so far fused), and every other
    capture's ``features`` cue against it (``cues``) with the level relative pose (``fits``; None: none)."""

    yaw_cam_deg: float | None
    cues: dict[str, Cue]
    fits: dict[str, Any]
    yaw_cam_sigma_deg: float = 0.0


def camera_features(
    views: list[CaptureView], cam: CaptureView | None, cam_cues: dict[str, Cue], s: AlignSettings
) -> CameraFeatures:
    """Step 4: features of every capture against the camera position (:func:`feature_cue`)."""
    pre = fuse_cues({k: c.model_copy() for k, c in cam_cues.items()}) if cam is not None else None
    yaw_cam = pre.yaw_deg if pre is not None else None
    yaw_cam_sigma = pre.sigma_deg if pre is not None and pre.sigma_deg is not None else 0.0
    cues: dict[str, Cue] = {}
    fits: dict[str, Any] = {}
    for v in views:
        if v is cam or cam is None or cam.features is None:
            continue
        if v.features is None:
            cues[v.id] = Cue(yaw_deg=None, ok=False, detail="features failed: no panorama")
            continue
        cues[v.id], fits[v.id] = feature_cue(
            cam.features,
            v.features,
            yaw_cam,
            yaw_cam_sigma,
            level_sigma_deg=s.sun.level_sigma_deg,
            max_baseline_elevation_deg=s.max_baseline_elevation_deg,
            ratio=s.match_ratio,
        )
    return CameraFeatures(yaw_cam, cues, fits, yaw_cam_sigma)


# --------------------------------------------------------------------------- the sun
def _to_frame(b: Blob, C: np.ndarray) -> Blob:
    d = C @ b.direction
    az, el = (math.degrees(float(v)) for v in angles_from_direction(d))
    return Blob(**{**b.__dict__, "direction": d, "azimuth_deg": wrap_deg(az), "elevation_deg": el})


def sun_inputs(
    campaign: Path,
    scene_id: str,
    views: list[CaptureView],
    cues: dict[str, dict[str, Cue]],
    store: Any,
    s: AlignSettings,
) -> list[CaptureSunInput]:
    """Step 5: what the sun's choice knows of each capture: its sun-frame candidates (with their sky
    fractions, in the refined level frame), its ephemeris, its yaw from features only (a compass-only
    capture is tested on elevation: its compass may be 90 deg off, then the sun gives its yaw and the
    compass is flagged), its compass yaw (a tie-breaker) and a human sun label."""
    inputs = []
    for v in views:
        pre = fuse_cues({k: c.model_copy() for k, c in cues[v.id].items() if k != "compass"})
        human = _human_sun(store, scene_id, v.id)
        blobs: list[Blob] = []
        if v.cap.sun_frame_path:
            frame = read_sun_frame(campaign, v.cap.sun_frame_path)
            blobs = find_candidates(frame, saturation=s.sun.saturation, max_candidates=s.sun.max_candidates)
            if v.normal_lin is not None:
                dirs = [b.direction for b in blobs]
                blobs = [
                    Blob(
                        **{
                            **b.__dict__,
                            "sky_fraction": sky_fraction(
                                v.normal_lin, b.direction, exclude=[d for d in dirs if d is not b.direction]
                            ),
                        }
                    )
                    for b in blobs
                ]
            blobs = [_to_frame(b, v.C) for b in blobs]
            note = ""
        else:
            note = "no sun frame (no low-exposure shot at this position)"
        if human is not None and human.found:
            assert human.azimuth_deg is not None and human.elevation_deg is not None  # a found sun has both
            d = v.C @ direction_from_angles(math.radians(human.azimuth_deg), math.radians(human.elevation_deg))
            az, el = (math.degrees(float(x)) for x in angles_from_direction(d))
            human = human.model_copy(update={"azimuth_deg": wrap_deg(az), "elevation_deg": el})
        compass = cues[v.id].get("compass")
        inputs.append(
            CaptureSunInput(
                v.id,
                blobs,
                v.ephemeris,
                pre.yaw_deg,
                pre.sigma_deg,
                v.heading,
                note,
                human,
                compass_yaw_deg=None if compass is None else compass.yaw_deg,
            )
        )
    return inputs


def sun_cues(
    views: list[CaptureView],
    cues: dict[str, dict[str, Cue]],
    sun: SceneSun,
    photo_eph: Ephemeris | None,
    s: AlignSettings,
    heading_p: float | None,
) -> dict[str, Cue]:
    """The ``sun`` cue of every capture: the scene's sun seen by the other captures (leave-one-out; their
    yaws from ``cues`` but the sun and the compass), minus this capture's; failing others, the ephemeris
    through the photo's compass."""
    pts = {}
    for v, cs in zip(views, sun.captures):
        if not cs.found:
            continue
        assert cs.azimuth_deg is not None and cs.elevation_deg is not None  # a found sun has both
        az, el = at_photo_time(cs.azimuth_deg, cs.elevation_deg, v.ephemeris, photo_eph, sun_moves=s.sun.sun_moves)
        pts[v.id] = (az, el, cs.uncertainty_deg or 0.1)
    out: dict[str, Cue] = {}
    for v, cs in zip(views, sun.captures):
        if v.id not in pts:
            out[v.id] = Cue(yaw_deg=None, ok=False, detail=f"no sun here: {cs.reason}")
            continue
        az_c, el_c, unc_c = pts[v.id]
        tilt = s.sun.level_sigma_deg * math.tan(math.radians(min(abs(el_c), 80.0)))
        own = math.hypot(unc_c / max(math.cos(math.radians(el_c)), 0.1), tilt)
        others = []
        for other in views:
            if other is v or other.id not in pts:
                continue
            oc = cues[other.id]
            y_other = (
                fuse_cues({k: c.model_copy() for k, c in oc.items() if k not in ("sun", "compass")}) if oc else None
            )
            if y_other is None or y_other.yaw_deg is None:
                continue
            az_o, el_o, unc_o = pts[other.id]
            sig_o = math.hypot(
                y_other.sigma_deg or 0.0,
                unc_o / max(math.cos(math.radians(el_o)), 0.1),
                s.sun.level_sigma_deg * math.tan(math.radians(min(abs(el_o), 80.0))),
            )
            others.append((wrap_deg(az_o + y_other.yaw_deg), sig_o, other.id))
        if others:
            w = np.array([1.0 / max(o[1], 0.05) ** 2 for o in others])
            ang = np.radians([o[0] for o in others])
            az_p = math.degrees(math.atan2(float(np.sum(w * np.sin(ang))), float(np.sum(w * np.cos(ang)))))
            sig = math.hypot(1.0 / math.sqrt(w.sum()), own)
            out[v.id] = Cue(
                yaw_deg=wrap_deg(az_p - az_c),
                sigma_deg=sig,
                ok=True,
                detail=f"sun azimuth {az_c:.2f} deg here vs {az_p:.2f} deg in the photo frame "
                f"(from {', '.join(o[2] for o in others)})",
            )
        elif photo_eph is not None and heading_p is not None:
            az_p = photo_azimuth_from_solar(photo_eph.azimuth_deg, heading_p)
            out[v.id] = Cue(
                yaw_deg=wrap_deg(az_p - az_c),
                sigma_deg=math.hypot(s.photo_compass_sigma_deg, own),
                ok=True,
                detail=f"sun azimuth {az_c:.2f} deg here vs the ephemeris {az_p:.2f} deg in the photo frame "
                "(through the photo's compass heading)",
            )
        else:
            out[v.id] = Cue(yaw_deg=None, ok=False, detail="the sun is seen here only, and there is no ephemeris")
    return out


@dataclass(frozen=True)
class SunStage:
    """Step 5: the scene's sun (``sun.motion`` says how the sun's motion was treated), the candidates
    another one outranked (:class:`~solidkit.align.sun.SunChoice`), whether the sun moves between the
    captures' times, and every capture's ``sun`` cue."""

    sun: SceneSun
    outranked: frozenset[tuple[str, int]]
    moves: bool
    cues: dict[str, Cue]


def sun_stage(
    views: list[CaptureView],
    cues: dict[str, dict[str, Cue]],
    inputs: list[CaptureSunInput],
    photo_eph: Ephemeris | None,
    heading_p: float | None,
    s: AlignSettings,
) -> SunStage:
    """Step 5: the scene's sun and the captures' sun cues, with the sun moving (ephemeris drift between the
    captures' times) or static, as ``s.sun_motion`` says; ``"auto"`` lets the images decide.

    Evidence for "auto": how well the sun cues agree with the captures' non-sun yaw cues
    (features), and how well the captures' sun elevations agree, under each hypothesis
    (chi-square with the cues' sigmas). The physical default (moving) stands without evidence.
    """
    modes = {"ephemeris": [True], "static": [False], "auto": [True, False]}[s.sun_motion]
    results = {}
    for moves in modes:
        ss = replace(s, sun=replace(s.sun, sun_moves=moves))
        choice = choose_sun(inputs, photo_ephemeris=photo_eph, photo_heading_deg=heading_p, settings=ss.sun)
        sun = choice.sun
        mode_cues = sun_cues(views, cues, sun, photo_eph, ss, heading_p)
        chi2, n = 0.0, 0
        for v in views:
            sc = mode_cues.get(v.id)
            others = {k: c.model_copy() for k, c in cues[v.id].items() if k in ("features", "photo_features")}
            if sc is None or sc.yaw_deg is None or not others:
                continue
            f = fuse_cues(others)
            if f.yaw_deg is None:
                continue
            r = wrap_deg(sc.yaw_deg - f.yaw_deg)
            chi2 += r**2 / ((sc.sigma_deg or 1.0) ** 2 + (f.sigma_deg or 1.0) ** 2)
            n += 1
        # the elevations of one sun seen from every position agree (no yaw involved)
        els = [(cast(float, cs.elevation_deg), v) for v, cs in zip(views, sun.captures) if cs.found]  # found: set
        if len(els) >= 2:
            moved = [at_photo_time(0.0, e, v.ephemeris, photo_eph, sun_moves=ss.sun.sun_moves)[1] for e, v in els]
            sig_el = math.hypot(s.sun.level_sigma_deg, s.sun.centroid_sigma_deg)
            chi2 += float(np.sum((np.array(moved) - np.mean(moved)) ** 2)) / sig_el**2
            n += len(els) - 1
        results[moves] = (chi2, n, choice, mode_cues)
    if len(results) == 1 or min(r[1] for r in results.values()) < 2 or photo_eph is None:
        moves = modes[0]
        why = f"sun motion: {'ephemeris drift applied' if moves else 'static'} ({s.sun_motion})"
    else:
        moves = results[True][0] <= results[False][0]
        why = (
            f"sun motion: {'moving (ephemeris drift applied)' if moves else 'static (no drift between captures)'}"
            f", chosen by the images: chi2 {results[True][0]:.1f} moving vs {results[False][0]:.1f} static "
            f" ({results[True][1]} comparisons: sun vs feature yaws, sun elevations)"
        )
    _, _, choice, mode_cues = results[moves]
    choice.sun.motion = why
    return SunStage(choice.sun, choice.outranked, bool(moves), mode_cues)


def explain_rejections(sun: SceneSun, outranked: frozenset[tuple[str, int]], probes: list[ProbeAlignment]) -> None:
    """Candidates rejected only because another one fitted better (``outranked``: their capture's yaw was not
    known when the sun was chosen: elevation alone, e.g. a glint in a vertical glass wall) get the reason the
    final yaw gives: how far from the scene's sun they are in the photo's panorama frame (in place)."""
    if not sun.found or sun.azimuth_deg is None:
        return
    assert sun.elevation_deg is not None  # set with the azimuth
    yaws = {p.id: p.yaw_deg for p in probes}
    for cs in sun.captures:
        yaw = yaws.get(cs.probe)
        if yaw is None:
            continue
        for k, c in enumerate(cs.candidates):
            if (cs.probe, k) in outranked:
                d_az = wrap_deg(c.azimuth_deg + yaw - sun.azimuth_deg)
                d = math.degrees(
                    float(
                        angular_distance(
                            direction_from_angles(math.radians(c.azimuth_deg + yaw), math.radians(c.elevation_deg)),
                            direction_from_angles(math.radians(sun.azimuth_deg), math.radians(sun.elevation_deg)),
                        )
                    )
                )
                c.reasons = [
                    f"not where the scene's sun is: {d:.1f} deg away (azimuth {d_az:+.1f} deg) once this capture's "
                    "yaw is known; same elevation as the sun: a mirror image (glint) in a vertical glass wall?"
                    if abs(c.elevation_deg - (cs.elevation_deg or c.elevation_deg)) < 1.5
                    else f"not where the scene's sun is: {d:.1f} deg away once this capture's yaw is known"
                ]
                c.scores["distance_to_scene_sun_deg"] = d


def rebase_on_camera(
    views: list[CaptureView],
    cues: dict[str, dict[str, Cue]],
    cam: CaptureView,
    cf: CameraFeatures,
    final_cam: tuple[float, float | None],
    min_shift_deg: float = 0.2,
) -> None:
    """The ``features`` cues of the other captures (relative poses to the camera position, turned by its yaw before
    the sun) turned by the camera position's final yaw instead, where the two differ by more than ``min_shift_deg``
    (in place; and the ``features_via_<id>`` cues through a capture so rebased): the probes then reach the photo's
    frame through the same rotation as the camera position (a camera yaw from its compass alone, corrected by the
    sun, left its probes with the compass' error)."""
    if cf.yaw_cam_deg is None:
        return
    yaw_f, sig_f = final_cam
    delta = wrap_deg(yaw_f - cf.yaw_cam_deg)
    if abs(delta) <= min_shift_deg:
        return
    moved = set()
    for v in views:
        c = cues[v.id].get("features")
        if v is cam or c is None or c.yaw_deg is None:
            continue
        rel = math.sqrt(max((c.sigma_deg or 0.0) ** 2 - cf.yaw_cam_sigma_deg**2, 0.0))
        c.yaw_deg, c.sigma_deg = wrap_deg(c.yaw_deg + delta), math.hypot(rel, sig_f or 0.0)
        c.detail += f"; turned by {cam.id}'s final yaw ({delta:+.2f} deg from its yaw before the sun)"
        moved.add(v.id)
    for v in views:
        for k, c in cues[v.id].items():
            if k.startswith("features_via_") and k[len("features_via_") :] in moved and c.yaw_deg is not None:
                c.yaw_deg = wrap_deg(c.yaw_deg + delta)
                c.detail += f"; turned by {cam.id}'s final yaw ({delta:+.2f} deg)"


def sun_through_final_yaws(
    sun: SceneSun,
    views: list[CaptureView],
    final: dict[str, tuple[float, float | None]],
    cues: dict[str, dict[str, Cue]],
    photo_eph: Ephemeris | None,
    heading_p: float | None,
    s: AlignSettings,
) -> None:
    """The scene's sun into the photo's panorama frame through the captures' final yaws (in place): the
    rotations the probes' products are made with, so that the sun and the probes cannot disagree silently.

    ``final``: each capture's final yaw (its refined level frame -> the photo's panorama frame) and sigma,
    degrees. The consensus of :func:`~solidkit.align.sun.consensus` took the yaws known before the sun; where
    the final yaws put the sun elsewhere (beyond three sigmas, at least 2 deg), the final yaws win and the
    scene is flagged ``sun_frame_conflict``, naming each capture whose yaw moved and the cues that lost there.
    A sun seen only from captures without a yaw before the sun gets its azimuth here.
    """
    if not sun.found or sun.elevation_deg is None:
        return
    by_id = {v.id: v for v in views}
    pts = []
    for cs in sun.captures:
        v, f = by_id.get(cs.probe), final.get(cs.probe)
        if not cs.found or v is None or f is None or "disagrees_with_scene" in flag_codes(cs.flags):
            continue
        assert cs.azimuth_deg is not None and cs.elevation_deg is not None  # a found sun has both
        az, el = at_photo_time(cs.azimuth_deg, cs.elevation_deg, v.ephemeris, photo_eph, sun_moves=s.sun.sun_moves)
        sig_dir = math.hypot(cs.uncertainty_deg or s.sun.centroid_sigma_deg, s.sun.level_sigma_deg)
        sig = math.hypot(f[1] or 0.0, sig_dir / max(math.cos(math.radians(el)), 0.2))
        pts.append((cs, wrap_deg(az + f[0]), sig))
    if not pts:
        return
    w = np.array([1.0 / max(p[2], 0.05) ** 2 for p in pts])
    ang = np.radians([p[1] for p in pts])
    az_f = math.degrees(math.atan2(float(np.sum(w * np.sin(ang))), float(np.sum(w * np.cos(ang)))))
    sig_f = 1.0 / math.sqrt(float(w.sum()))
    before = sun.azimuth_deg
    if before is not None:
        d = wrap_deg(az_f - before)
        if abs(d) * math.cos(math.radians(sun.elevation_deg)) <= max(
            2.0, 3.0 * math.hypot(sig_f, sun.uncertainty_deg or 0.0)
        ):
            return
        moved = []
        for cs, _, _ in pts:
            lost = [
                f"{k} ({c.residual_deg:+.1f} deg)" if c.residual_deg is not None else k
                for k, c in cues.get(cs.probe, {}).items()
                if c.yaw_deg is not None and not c.ok
            ]
            used = [k for k, c in cues.get(cs.probe, {}).items() if c.ok]
            moved.append(
                f"{cs.probe}: yaw from {', '.join(used) or 'nothing'}" + (f"; lost: {', '.join(lost)}" if lost else "")
            )
        sun.flags = [
            *sun.flags,
            str(
                Flag(
                    FlagCode.SUN_FRAME_CONFLICT,
                    f"the sun's azimuth through the yaws before the sun was {before:.1f} deg, through the final "
                    f"yaws (the probes' rotations) {az_f:.1f} deg ({d:+.1f}); the final yaws kept ({'; '.join(moved)})",
                )
            ),
        ]
    sun.azimuth_deg = az_f
    if before is None:
        sun.uncertainty_deg = math.hypot(sun.uncertainty_deg or 0.0, sig_f * math.cos(math.radians(sun.elevation_deg)))
    if heading_p is not None:
        sun.world_azimuth_deg = solar_azimuth_from_photo(az_f, heading_p)
        sun.world_elevation_deg = sun.elevation_deg
        for cs, az, _ in pts:
            cs.world_azimuth_deg = solar_azimuth_from_photo(az, heading_p)


#: Flag codes of a capture's yaw that make every yaw derived from it doubtful (beside ``yaw_doubtful`` itself).
_YAW_DOUBT_CODES = (
    FlagCode.NO_YAW.value,
    FlagCode.SINGLE_CUE.value,
    FlagCode.NO_AGREEMENT.value,
    FlagCode.FEATURES_FAILED.value,
    FlagCode.YAW_FROM_STREET_LINES.value,
    FlagCode.YAW_FROM_COMPASSES.value,
    FlagCode.YAW_FROM_SKY.value,
    FlagCode.LABEL_DIFFERS.value,
    FlagCode.YAW_DOUBTFUL.value,
)
#: Flag codes of the scene's sun (or a capture's sun) that make a yaw taken from the sun doubtful.
_SUN_DOUBT_CODES = (
    FlagCode.EPHEMERIS_DISAGREES.value,
    FlagCode.EPHEMERIS_AZIMUTH_DISAGREES.value,
    FlagCode.POSITION_DISAGREES.value,
    FlagCode.SUN_FRAME_CONFLICT.value,
    FlagCode.SUN_OFF_EPHEMERIS.value,
    FlagCode.DISAGREES_WITH_SCENE.value,
)


def clock_doubts(
    scene_flags: list[str], photo: list[str], far: list[str], sun: SceneSun, probes: list[ProbeAlignment]
) -> list[str]:
    """The scene's clock doubts carried to what they touched (in place), and the scene's flags with its
    ``clock_mismatch`` flags joined into one (a test set keeps one flag per code).

    The photo's own clock off its GPS time (``photo``: the details of :func:`photo_clock_mismatch`) puts every
    capture's time against the photo's in doubt (which captures are near the photo, the sun's drift to the
    photo's time, the light the probe saw at the photo's moment): every capture is flagged ``clock_mismatch``,
    and so is the scene's sun where it has a direction (seen, or the ephemeris'). A capture taken more than an
    hour from the photo (``far``, :func:`clock_mismatch`) is flagged at itself (no sun drift correction there; its
    light may not be the photo's). A capture both doubts touch gets one flag saying both.
    """
    clock = [f for f in scene_flags if Flag.parse(f).code == FlagCode.CLOCK_MISMATCH.value]
    if len(clock) > 1:
        joined = str(Flag(FlagCode.CLOCK_MISMATCH, "; ".join(Flag.parse(f).detail for f in clock)))
        scene_flags = [f for f in scene_flags if f not in clock[1:]]
        scene_flags[scene_flags.index(clock[0])] = joined
    if not photo and not far:
        return scene_flags
    photo_why = f"the photo's clock is off its GPS time ({'; '.join(photo)})" if photo else ""
    for pa in probes:
        why = [f"{photo_why}: this capture's time against the photo's is unknown"] if photo else []
        if pa.id in far:
            why.append(
                "taken more than an hour from the photo (camera clocks or UTC offsets disagree); no sun drift "
                "correction here"
            )
        if why:
            pa.flags = [*pa.flags, str(Flag(FlagCode.CLOCK_MISMATCH, "; ".join(why)))]
    if photo and (sun.found or sun.azimuth_deg is not None or sun.world_azimuth_deg is not None):
        sun.flags = [
            *sun.flags,
            str(Flag(FlagCode.CLOCK_MISMATCH, f"{photo_why}: the sun's direction at the photo's time rests on it")),
        ]
    return scene_flags


def flag_doubtful_yaws(
    sun: SceneSun, probes: list[ProbeAlignment], camera_probe: str | None, limit_deg: float = 2.0
) -> None:
    """``yaw_doubtful`` on every capture whose yaw may be more than ``limit_deg`` off without another flag saying
    so (in place): three sigmas of its yaw above the limit; a yaw that used the scene's sun where the sun is
    flagged (:data:`_SUN_DOUBT_CODES`, the scene's or any capture's); a yaw relative to another capture (the
    camera position's ``features``, ``features_via_<id>``) whose own yaw is doubtful. Captures the doubt of
    another reaches are flagged after it (the camera position first)."""
    sun_doubts = sorted(
        {c for c in flag_codes(sun.flags) if c in _SUN_DOUBT_CODES}
        | {c for cs in sun.captures for c in flag_codes(cs.flags) if c in _SUN_DOUBT_CODES}
    )
    by_id = {p.id: p for p in probes}
    order = sorted(probes, key=lambda p: p.id != camera_probe)
    for _ in range(2):  # a chain through a capture flagged in the first pass
        for pa in order:
            if pa.yaw_deg is None or pa.yaw_source != "auto" or FlagCode.YAW_DOUBTFUL.value in flag_codes(pa.flags):
                continue
            why = []
            sig = pa.yaw_sigma_deg
            if (
                sig is not None
                and 3.0 * sig > limit_deg
                and not any(c in _YAW_DOUBT_CODES for c in flag_codes(pa.flags))
            ):
                why.append(f"three sigmas of its yaw are {3.0 * sig:.1f} deg")
            sun_cue = pa.cues.get("sun")
            if sun_doubts and sun_cue is not None and sun_cue.ok and sun_cue.yaw_deg is not None:
                why.append(f"its yaw uses the scene's sun, which is flagged {', '.join(sun_doubts)}")
            for k, c in pa.cues.items():
                if not c.ok or c.yaw_deg is None:
                    continue
                ref = (
                    camera_probe
                    if k == "features"
                    else k[len("features_via_") :]
                    if k.startswith("features_via_")
                    else None
                )
                other = by_id.get(ref) if ref else None
                if other is not None and other is not pa:
                    bad = [c2 for c2 in flag_codes(other.flags) if c2 in _YAW_DOUBT_CODES]
                    if bad:
                        why.append(
                            f"its yaw is relative to {other.id}'s, which is flagged {', '.join(dict.fromkeys(bad))}"
                        )
            if why:
                pa.flags = [
                    *pa.flags,
                    str(Flag(FlagCode.YAW_DOUBTFUL, f"may be more than {limit_deg:g} deg off: {'; '.join(why)}")),
                ]


def _capture_sun_to_product_frame(cs: CaptureSun, C: np.ndarray) -> None:
    """Directions of a capture's sun result from the refined level frame back to its sun-frame product's."""
    if np.allclose(C, np.eye(3)):
        return

    def back(az: float, el: float) -> tuple[float, float]:
        d = C.T @ direction_from_angles(math.radians(az), math.radians(el))
        a, e = (math.degrees(float(v)) for v in angles_from_direction(d))
        return wrap_deg(a), e

    if cs.found:  # (a human label comes back to its own numbers)
        assert cs.azimuth_deg is not None and cs.elevation_deg is not None
        cs.azimuth_deg, cs.elevation_deg = back(cs.azimuth_deg, cs.elevation_deg)
    for c in cs.candidates:
        c.azimuth_deg, c.elevation_deg = back(c.azimuth_deg, c.elevation_deg)


# --------------------------------------------------------------------------- yaw cues for captures still without one
def _non_compass(cues: dict[str, Cue]) -> Any:
    """The fusion of a capture's yaw cues other than its compass."""
    return fuse_cues({k: c.model_copy() for k, c in cues.items() if k != "compass" and c.yaw_deg is not None})


def _compass_only(cues: dict[str, Cue]) -> bool:
    """True when the compass is the only cue that gives the capture a yaw."""
    compass = cues.get("compass")
    return compass is not None and compass.yaw_deg is not None and _non_compass(cues).yaw_deg is None


def chain_cues(
    views: list[CaptureView], cues: dict[str, dict[str, Cue]], cam: CaptureView | None, s: AlignSettings
) -> dict[str, dict[str, Cue]]:
    """``features_via_<id>`` cues (per capture id) for captures left with the compass alone (features failed
    against the camera position, no sun): features against the other captures, whose yaws (features, sun;
    never the compass) carry them over. A chain adds the other capture's error: a fallback only."""
    known = {}
    for v in views:
        f = fuse_cues({k: c.model_copy() for k, c in cues[v.id].items() if k != "compass"})
        if f.yaw_deg is not None:
            known[v.id] = (f.yaw_deg, f.sigma_deg or 0.0, v)
    out: dict[str, dict[str, Cue]] = {}
    for v in views:
        own, sun = cues[v.id].get("features"), cues[v.id].get("sun")
        if v is cam or v.features is None or own is None or own.yaw_deg is not None or (sun is not None and sun.ok):
            continue
        for oid, (yaw_o, sig_o, other) in known.items():
            if other is v or other is cam or other.features is None:
                continue
            cue, _ = feature_cue(
                other.features,
                v.features,
                yaw_o,
                sig_o,
                level_sigma_deg=s.sun.level_sigma_deg,
                max_baseline_elevation_deg=s.max_baseline_elevation_deg,
                ratio=s.match_ratio,
                reference=oid,
            )
            if cue.yaw_deg is not None:
                out.setdefault(v.id, {})[f"features_via_{oid}"] = cue
    return out


def _photo_lines(campaign: Path, photo: PhotoInfo | None) -> tuple[np.ndarray, np.ndarray] | None:
    """The photo's line segments as great-circle normals in its level panorama frame (its pitch/roll)."""
    if photo is None:
        return None
    R = np.asarray(rotation_from_ypr(0.0, math.radians(photo.pitch_deg or 0.0), math.radians(photo.roll_deg or 0.0)))
    return photo_line_normals(read_ldr(campaign / photo.path), np.asarray(photo.K_full), R)


def manhattan_cues(
    views: list[CaptureView],
    cues: dict[str, dict[str, Cue]],
    s: AlignSettings,
    photo_lines: Callable[[], tuple[np.ndarray, np.ndarray] | None] | None = None,
) -> dict[str, Cue]:
    """``manhattan`` cues (:mod:`solidkit.align.manhattan`, per capture id) for captures left with the compass alone.

    The street's horizontal vanishing azimuth in the photo's panorama frame (modulo 90°) comes from
    the captures whose yaw other cues fixed and from the photo itself (yaw 0 in its own frame; its
    pitch/roll level its lines): a robust mean over them. A lone capture's own vanishing azimuth
    then gives its yaw modulo 90°, the quadrant nearest to its compass.
    """
    lone = [v for v in views if v.normal_lin is not None and _compass_only(cues[v.id])]
    if not lone:
        return {}
    fits = {}
    for v in views:
        if v.normal_lin is not None:
            fits[v.id] = vanishing_azimuth(*line_normals(v.normal_lin, linear=True, C=v.C))
    members = []
    for v in views:
        f, known = fits.get(v.id), _non_compass(cues[v.id])
        if f is not None and known.yaw_deg is not None and f.ambiguity < 0.95:
            members.append(
                ((f.azimuth_deg + known.yaw_deg) % 90.0, math.hypot(f.sigma_deg, known.sigma_deg or 0.0), v.id)
            )
    lines = photo_lines() if photo_lines is not None else None
    fp = vanishing_azimuth(*lines) if lines is not None else None
    if fp is not None and fp.ambiguity < 0.95:
        # the photo's pitch/roll (features or field notes) tilt its lines: a floor of 0.5 deg
        members.append((fp.azimuth_deg % 90.0, math.hypot(fp.sigma_deg, 0.5), "the photo"))
    if not members:
        why = "neither the photo nor a capture with a known yaw shows the street's lines"
        return {v.id: Cue(yaw_deg=None, ok=False, detail=why) for v in lone}

    def mean90(vals: list[float], w: list[float]) -> float:  # circular mean with period 90 deg
        ang = np.radians(np.asarray(vals) * 4.0)
        return (math.degrees(math.atan2(float(np.dot(w, np.sin(ang))), float(np.dot(w, np.cos(ang))))) / 4.0) % 90.0

    def near(a: float, b: float) -> bool:
        return abs(wrap_deg(4.0 * (a - b)) / 4.0) <= 2.0

    # the largest group that agrees within 2 deg (a capture whose lines picked the wrong peak is left out)
    centre = max(members, key=lambda m: (sum(near(m[0], o[0]) for o in members), -m[1]))[0]
    members = [m for m in members if near(m[0], centre)]
    w = [1.0 / max(m[1], 0.1) ** 2 for m in members]
    ref = mean90([m[0] for m in members], w)
    ref_sigma = 1.0 / math.sqrt(sum(w))
    out: dict[str, Cue] = {}
    for v in lone:
        f = fits.get(v.id)
        if f is None or f.ambiguity > s.manhattan_max_ambiguity:
            why = "too few line segments" if f is None else f"no clear street direction (ambiguity {f.ambiguity:.2f})"
            out[v.id] = Cue(yaw_deg=None, ok=False, detail=f"manhattan: {why}")
            continue
        compass = float(cast(float, cues[v.id]["compass"].yaw_deg))  # a lone capture has a compass yaw
        base = ref - f.azimuth_deg
        yaw = wrap_deg(base + 90.0 * round((compass - base) / 90.0))
        sigma = math.hypot(f.sigma_deg, ref_sigma, s.manhattan_model_sigma_deg)
        out[v.id] = Cue(
            yaw_deg=yaw,
            sigma_deg=sigma,
            ok=True,
            detail=(
                f"street lines at {f.azimuth_deg:.2f} deg (mod 90) here vs {ref:.2f} deg in the photo frame "
                f"(from {', '.join(m[2] for m in members)}); quadrant from the compass ({f.n_segments} segments)"
            ),
        )
    return out


@dataclass(frozen=True)
class LinkStage:
    """The ``linked`` cue of each capture that was left with the compass alone, and the flags that go with
    it (``yaw_from_compasses``, ``yaw_from_sky``, ``yaw_from_street_lines``), per capture id."""

    cues: dict[str, Cue] = field(default_factory=dict)
    flags: dict[str, list[str]] = field(default_factory=dict)


def link_cues(
    views: list[CaptureView],
    cues: dict[str, dict[str, Cue]],
    s: AlignSettings,
    sun_moves: bool = False,
    log: Callable[[str], None] = lambda s: None,
) -> LinkStage:
    """The ``linked`` cue (:mod:`solidkit.align.links`) for captures still left with the compass alone.

    Links: features between every such capture and every other capture (level relative pose), and
    their skies (:mod:`solidkit.align.sky`); the yaws of the other captures (any cue but the
    compass) and every lone capture's compass are the absolute links. A lone capture whose group
    holds no capture of known yaw gets the mean of the group's compasses (flagged
    ``yaw_from_compasses``); one whose anchors are street lines only stays flagged
    ``yaw_from_street_lines``. The sky's pattern turns with the sun: when the scene's sun moves
    (``sun_moves``, as chosen for the sun cues), a sky link is corrected by the ephemeris' azimuth
    drift between the two captures' times.
    """
    lone = [v for v in views if v.features is not None and _compass_only(cues[v.id])]
    if not lone:
        return LinkStage()
    known = {}
    for v in views:
        if v.features is not None and v not in lone:
            f = _non_compass(cues[v.id])
            if f.yaw_deg is not None:
                vc = cues[v.id]
                street = (
                    "manhattan" in vc
                    and vc["manhattan"].ok
                    and len([c for k, c in vc.items() if c.ok and k != "compass"]) == 1
                )
                known[v.id] = (f.yaw_deg, f.sigma_deg or 0.0, street)
    sky = {}
    if s.sky:
        for v in views:
            if v.normal_lin is not None and (v in lone or v.id in known):
                lin = np.asarray(v.normal_lin, np.float32)
                small = rotate(lin, v.C, "linear", 512) if not np.allclose(v.C, np.eye(3)) else lin
                sky[v.id] = sky_layer(small, saturation=None if v.linear else 0.98)
    links: list[Link] = []
    lone_ids = [v.id for v in lone]
    pairs = [
        (a, b)
        for i, a in enumerate(views)
        for b in views[i + 1 :]
        if (a in lone or b in lone) and (a.id in known or a in lone) and (b.id in known or b in lone)
    ]
    for a, b in pairs:
        if b.id not in lone_ids:
            a, b = b, a  # b is lone
        rel: list[tuple[str, float, float, str]] = []
        assert a.features is not None and b.features is not None  # lone and known captures have features
        cue, fit = feature_cue(
            a.features,
            b.features,
            0.0,
            0.0,
            level_sigma_deg=s.sun.level_sigma_deg,
            max_baseline_elevation_deg=s.max_baseline_elevation_deg,
            ratio=s.match_ratio,
        )
        if cue.yaw_deg is not None:
            assert cue.sigma_deg is not None and fit is not None  # a cue with a yaw has its sigma and fit
            rel.append(("features", cue.yaw_deg, cue.sigma_deg, f"{fit.n_inliers} inliers"))
        if a.id in sky and b.id in sky:
            sky_fit, why = relative_sky_yaw(
                sky[a.id],
                sky[b.id],
                min_overlap=s.sky_min_overlap,
                correlation_px=s.sky_correlation_px,
                min_delta_chi2=s.sky_min_delta_chi2,
            )
            if sky_fit is not None:
                drift, what = 0.0, f"sigma {sky_fit.sigma_deg:.2f} deg"
                if (
                    sun_moves
                    and a.ephemeris is not None
                    and b.ephemeris is not None
                    and hours_apart(a.ephemeris, b.ephemeris) <= DRIFT_HOURS
                ):
                    drift = wrap_deg(b.ephemeris.azimuth_deg - a.ephemeris.azimuth_deg)
                    what += f", sun drift {drift:+.2f} deg applied"
                yaw = without_sun_drift(sky_fit.yaw_deg, 0.0, drift)
                rel.append(("sky", yaw, sky_fit.sigma_deg, what))
        for kind, yaw, sig, what in rel:
            if a.id in known:
                ya, sa, street = known[a.id]
                links.append(
                    Link(
                        GROUND,
                        b.id,
                        wrap_deg(ya + yaw),
                        math.hypot(sig, sa),
                        f"{kind}_via_{a.id}",
                        f"{kind} {b.id} to {a.id} ({what}){', whose yaw is from street lines' if street else ''}",
                        street_lines=street,
                    )
                )
            else:
                links.append(Link(a.id, b.id, yaw, sig, kind, f"{kind} {a.id}-{b.id} ({what})"))
        log(f"links {a.id}-{b.id}: " + (", ".join(f"{k} {y:+.2f}+-{g:.2f}" for k, y, g, _ in rel) or "none"))
    for v in lone:
        c = cues[v.id]["compass"]
        links.append(
            Link(GROUND, v.id, float(cast(float, c.yaw_deg)), float(c.sigma_deg or s.sun.compass_sigma_deg), "compass")
        )
    solved = solve_links(lone_ids, links)
    out = LinkStage()
    for v in lone:
        r = solved.get(v.id)
        if r is None:
            out.cues[v.id] = Cue(yaw_deg=None, ok=False, detail="no feature or sky link to another capture")
            continue
        parts = [e.detail for e in r.used] + [e.detail for e in r.anchors]
        detail = "; ".join(dict.fromkeys(parts))
        if r.compasses:
            detail += f"; compasses of {', '.join(r.compasses)}"
        if r.rejected:
            detail += f"; inconsistent, left out: {', '.join(e.detail for e in r.rejected)}"
        out.cues[v.id] = Cue(yaw_deg=r.yaw_deg, sigma_deg=r.sigma_deg, ok=True, detail=detail)
        flags = out.flags.setdefault(v.id, [])
        if not r.anchors:
            flags.append(
                str(
                    Flag(
                        FlagCode.YAW_FROM_COMPASSES,
                        f"the compasses of {', '.join(r.compasses)} linked by features or sky to this capture "
                        "fix its yaw (no capture of known yaw in its group): review",
                    )
                )
            )
        elif all(e.kind.startswith("sky") for e in r.used + r.anchors):
            flags.append(
                str(
                    Flag(
                        FlagCode.YAW_FROM_SKY,
                        f"only the sky's radiance pattern ({len(r.used) + len(r.anchors)} sky link(s), sigma "
                        f"{r.sigma_deg:.2f} deg) fixes this yaw beside the compass: review",
                    )
                )
            )
        elif all(e.street_lines for e in r.anchors):
            flags.append(
                str(
                    Flag(
                        FlagCode.YAW_FROM_STREET_LINES,
                        "linked to captures whose yaw only street lines fix "
                        f"({', '.join(e.kind for e in r.anchors)}): review",
                    )
                )
            )
    return out


# --------------------------------------------------------------------------- final yaws and probe pixels
def _levelling_record(view: CaptureView) -> tuple[Levelling, float]:
    """The capture's levelling (body -> refined level frame) and the tiny yaw ``y0`` that composing
    the correction with the metadata's levelling leaves: ``C R(0, p_m, r_m) = R(y0, p, r)``."""
    if view.cap.normal is None:
        return Levelling(pitch_deg=0.0, roll_deg=0.0, source="none"), 0.0
    R = view.C @ np.asarray(rotation_from_ypr(0.0, math.radians(view.pitch), math.radians(view.roll)))
    y0, p, r = (math.degrees(float(v)) for v in ypr_from_rotation(R))
    t = view.tilt
    refined = not np.allclose(view.C, np.eye(3))
    lev = Levelling(
        pitch_deg=p,
        roll_deg=r,
        source="metadata+tilt" if refined else "metadata",
        metadata_pitch_deg=view.pitch,
        metadata_roll_deg=view.roll,
        residual_tilt_deg=None if t is None else t.tilt_deg,
        tilt_uncertainty_deg=None if t is None else t.uncertainty_deg,
        tilt_reliable=None if t is None else t.reliable,
        confidence=None if t is None or not t.reliable else float(1.0 / (1.0 + t.uncertainty_deg)),
    )
    return lev, y0


@dataclass(frozen=True)
class CaptureYaw:
    """A capture's final yaw (degrees; None: unknown) in the level frame its cues were measured in, its
    source (``auto`` or a human label's), 1-sigma and RMS residual of the agreeing cues, and its flags."""

    yaw_deg: float | None
    source: str
    sigma_deg: float | None
    residual_deg: float | None
    flags: list[str]


def capture_yaw(view: CaptureView, cues: dict[str, Cue], link_flags: list[str], label: Any) -> CaptureYaw:
    """The consensus of a capture's cues (:func:`fuse_cues`, which marks the cues in place); a human
    ``heading`` label (``label``; None: none) overrides it and joins ``cues`` as the ``label`` cue."""
    fused = fuse_cues(cues)
    flags = list(view.flags) + fused.flags
    yaw, source = fused.yaw_deg, "auto"
    if label is not None:
        lyaw = float(label.value["yaw_deg"])
        cues["label"] = Cue(
            yaw_deg=lyaw,
            ok=True,
            weight=1.0,
            detail=f"{label.source} label by {label.annotator}",
            residual_deg=None if yaw is None else wrap_deg(lyaw - yaw),
        )
        if yaw is not None and abs(wrap_deg(lyaw - yaw)) > 2.0:
            flags.append(
                str(
                    Flag(
                        FlagCode.LABEL_DIFFERS,
                        f"the {label.source} heading is {wrap_deg(lyaw - yaw):+.1f} deg from the cues",
                    )
                )
            )
        yaw, source = lyaw, label.source
    if "features" in cues and not cues["features"].ok and cues["features"].yaw_deg is None and yaw is not None:
        used = [k for k, c in cues.items() if c.ok and k != "features"]
        flags.append(
            str(
                Flag(
                    FlagCode.FEATURES_FAILED,
                    f"no match to the camera position; yaw from {', '.join(used) or 'nothing'}",
                )
            )
        )
    if "manhattan" in cues and cues["manhattan"].ok and source == "auto":
        flags.append(
            str(
                Flag(
                    FlagCode.YAW_FROM_STREET_LINES,
                    "only the street's line directions (modulo 90 deg, quadrant from the compass) fix this yaw: review",
                )
            )
        )
    if "linked" in cues and cues["linked"].ok and source == "auto":
        flags.extend(link_flags)
    return CaptureYaw(yaw, source, fused.sigma_deg, fused.residual_deg, flags)


@dataclass(frozen=True)
class ProbePixel:
    """Where a probe capture is in the photo (full-resolution pixels): the pixel used (``pixel_full``, from
    ``pixel_source``), the one the geometry predicts (with the 1-sigma angle of its direction), their
    distance and angle, and the flags about it (codes ``pixel_...``, ``no_pixel``)."""

    pixel_full: list[float] | None = None
    pixel_source: str | None = None
    pixel_geometry: list[float] | None = None
    pixel_geometry_sigma_deg: float | None = None
    pixel_error_px: float | None = None
    pixel_error_deg: float | None = None
    flags: tuple[str, ...] = ()

    def fields(self) -> dict[str, Any]:
        """The :class:`~solidkit.align.schema.ProbeAlignment` fields (all but the flags)."""
        return {
            k: getattr(self, k)
            for k in (
                "pixel_full",
                "pixel_source",
                "pixel_geometry",
                "pixel_geometry_sigma_deg",
                "pixel_error_px",
                "pixel_error_deg",
            )
        }


def probe_pixel(
    view: CaptureView,
    fit: Any,
    label: Any,
    photo: PhotoInfo,
    yaw_cam: float | None,
    s: AlignSettings,
    yaw_cam_sigma: float = 0.0,
) -> ProbePixel:
    """Pixel of the probe in the photo (field notes > human ``probe_pixel`` label > geometry) and its
    geometric check: the direction from the camera position to the probe capture (the level relative
    pose ``fit`` against the camera position, turned by the camera capture's yaw ``yaw_cam``, its final
    one: the rotation its products have), projected into the photo; the check's tolerance takes the
    camera yaw's sigma ``yaw_cam_sigma`` (degrees) in."""
    geom, geom_sigma = None, None
    if fit is not None and yaw_cam is not None and fit.t_support >= s.min_translation_support:
        d_lcam = fit.centre2_in_1
        d_p = np.asarray(rotation_from_ypr(math.radians(yaw_cam), 0.0, 0.0)) @ d_lcam
        pitch, roll = math.radians(photo.pitch_deg or 0.0), math.radians(photo.roll_deg or 0.0)
        c = np.asarray(rotation_from_ypr(0.0, pitch, roll)).T @ d_p
        if c[2] > 1e-6:
            p = np.asarray(photo.K_full) @ (c / c[2])
            geom = [float(p[0]), float(p[1])]
            geom_sigma = math.degrees(fit.t_sigma) if math.isfinite(fit.t_sigma) else None
    flags: list[str] = []
    pixel, source = None, None
    if view.cap.probe.photo_pixel is not None:
        pixel, source = [float(v) for v in view.cap.probe.photo_pixel], "field_notes"
        if label is not None:
            pixel, source = [float(label.value["x"]), float(label.value["y"])], "label"
    elif label is not None:
        pixel, source = [float(label.value["x"]), float(label.value["y"])], "label"
    elif geom is not None:
        pixel, source = geom, "geometry"
        flags.append(
            str(Flag(FlagCode.PIXEL_FROM_GEOMETRY, "no marked pixel; the relative pose's direction is used (review)"))
        )
    else:
        flags.append(
            str(Flag(FlagCode.NO_PIXEL, "no marked pixel and no relative pose with parallax to the camera position"))
        )
    err = ang = None
    w, h = photo.size
    if geom is not None and pixel is not None and source != "geometry":
        err = math.dist(geom, pixel)
        r = rays_from_pixels(np.array([pixel, geom]), np.asarray(photo.K_full))
        ang = math.degrees(float(angular_distance(r[0], r[1])))
        # tolerance: n_sigma of the baseline direction's own uncertainty (plus the lens's height above the marked
        # surface, ~1 deg at a few metres), never below pixel_tolerance_deg
        sig = geom_sigma if geom_sigma is not None else math.inf
        tol = max(s.pixel_tolerance_deg, s.pixel_n_sigma * math.hypot(sig, 1.0, yaw_cam_sigma))
        # a pose from few matches can be wrong beyond its sigma (measured: 13 inliers in a glass scene, 11 deg off)
        if ang > tol and fit.n_inliers >= s.min_pixel_check_inliers:
            flags.append(
                str(
                    Flag(
                        FlagCode.PIXEL_DISAGREES,
                        f"the marked pixel is {ang:.1f} deg ({err:.0f} px) from the direction of the "
                        f"probe capture seen from the camera position ({geom[0]:.0f}, {geom[1]:.0f}; tolerance "
                        f"{tol:.1f} deg): wrong probe marked?",
                    )
                )
            )
    if pixel is not None and not (-0.5 <= pixel[0] <= w - 0.5 and -0.5 <= pixel[1] <= h - 0.5):
        flags.append(FlagCode.PIXEL_OUTSIDE_PHOTO.value)
    return ProbePixel(pixel, source, geom, geom_sigma, err, ang, tuple(flags))


def _human(store: Any, kind: str, key: str) -> Any:
    if store is None:
        return None
    lab = store.get(kind, key)
    return lab if lab is not None and lab.source in ("annotator", "reviewed") else None


def _human_sun(store: Any, sid: str, pid: str) -> CaptureSun | None:
    lab = _human(store, "sun", f"{sid}/{pid}")
    if lab is None:
        return None
    v = lab.value
    return CaptureSun(
        probe=pid,
        found=bool(v["found"]),
        azimuth_deg=v.get("azimuth_deg"),
        elevation_deg=v.get("elevation_deg"),
        uncertainty_deg=v.get("uncertainty_deg"),
        reason=f"{lab.source} label by {lab.annotator}",
        source=lab.source,
    )


# --------------------------------------------------------------------------- the scene
def align_scene(
    campaign: Path,
    manifest: Manifest,
    scene: Scene,
    settings: AlignSettings,
    store: Any = None,
    log: Callable[[str], None] = lambda s: None,
) -> tuple[SceneAlignment, dict[str, Any]]:
    """Align one scene (module doc), step by step: :func:`scene_photo`, :func:`capture_view` per capture,
    :func:`photo_stage`, :func:`compass_cue`, :func:`camera_features`, :func:`sun_inputs` and
    :func:`sun_stage`, :func:`chain_cues`, :func:`manhattan_cues`, :func:`link_cues`, then
    :func:`capture_yaw` and :func:`probe_pixel` per capture. Returns the scene's alignment and per-capture
    working data (``{"yaw_sigma": {probe: deg}}``) for the products and report."""
    s = settings
    ph = scene_photo(campaign, manifest, scene)
    scene_flags = list(ph.flags)
    views = [capture_view(campaign, manifest, scene.id, c, s, ph.place, log) for c in captures_of(manifest, scene)]
    scene_flags += clock_mismatch(ph.ephemeris, views)
    far = far_from_photo(ph.ephemeris, views)
    photo_clock = [f.detail for f in map(Flag.parse, ph.flags) if f.code == FlagCode.CLOCK_MISMATCH.value]
    by_id = {v.id: v for v in views}
    cam = by_id.get(ph.camera_probe) if ph.camera_probe else None
    heading_p = ph.heading_deg

    # yaw cues without the sun; each capture's cues in the order they are found (the consensus reads them so)
    cues: dict[str, dict[str, Cue]] = {v.id: {} for v in views}
    pst = photo_stage(campaign, ph.info, cam, s)
    photo = pst.photo
    scene_flags += pst.flags
    if pst.cue is not None:
        assert cam is not None  # the photo is matched against the camera position's capture
        cues[cam.id]["photo_features"] = pst.cue
    for v in views:
        cues[v.id]["compass"] = compass_cue(v, heading_p, s)
    cf = camera_features(views, cam, cues[cam.id] if cam is not None else {}, s)
    for vid, cue in cf.cues.items():
        cues[vid]["features"] = cue

    # the sun, then the cues for captures still left with the compass alone
    sst = sun_stage(views, cues, sun_inputs(campaign, scene.id, views, cues, store, s), ph.ephemeris, heading_p, s)
    for vid, cue in sst.cues.items():
        cues[vid]["sun"] = cue
    for vid, more in chain_cues(views, cues, cam, s).items():
        cues[vid].update(more)
    if s.manhattan:
        for vid, cue in manhattan_cues(views, cues, s, photo_lines=lambda: _photo_lines(campaign, photo)).items():
            cues[vid]["manhattan"] = cue
    lst = link_cues(views, cues, s, sst.moves, log) if s.links else LinkStage()
    for vid, cue in lst.cues.items():
        cues[vid]["linked"] = cue

    # final yaws, probe pixels
    probes: list[ProbeAlignment] = []
    yaw_sigma: dict[str, float | None] = {}
    final: dict[str, tuple[float, float | None]] = {}  # final yaw (refined level frame) and sigma, per capture
    for v in views:
        cy = capture_yaw(v, cues[v.id], lst.flags.get(v.id, []), _human(store, "heading", f"{scene.id}/{v.id}"))
        yaw_sigma[v.id] = cy.sigma_deg
        role = "camera" if v.id == ph.camera_probe else "probe"
        levelling, y0 = _levelling_record(v)
        yaw = cy.yaw_deg
        if yaw is not None and cy.source == "auto":
            yaw = wrap_deg(yaw + y0)  # R_y(yaw) C R_meta = R_y(yaw + y0) R(0, p, r)
        if yaw is not None:
            final[v.id] = (wrap_deg(yaw - y0), cy.sigma_deg)
            if v is cam:
                rebase_on_camera(views, cues, cam, cf, final[v.id])
        px = ProbePixel()
        if role == "probe" and photo is not None:
            # the camera position's final yaw (it comes first): the probes' pixels and rotations share it
            cam_yaw, cam_sigma = final.get(cam.id, (cf.yaw_cam_deg, None)) if cam is not None else (None, None)
            px = probe_pixel(
                v,
                cf.fits.get(v.id),
                _human(store, "probe_pixel", f"{scene.id}/{v.id}"),
                photo,
                cam_yaw,
                s,
                cam_sigma or 0.0,
            )
        probes.append(
            ProbeAlignment(
                id=v.id,
                role=role,
                levelling=levelling,
                rotation=body_to_pano(
                    yaw if yaw is not None else 0.0, levelling.pitch_deg, levelling.roll_deg
                ).tolist(),
                yaw_deg=yaw,
                yaw_source=cy.source,
                residual_deg=cy.residual_deg,
                yaw_sigma_deg=cy.sigma_deg if cy.source == "auto" else None,
                cues=cues[v.id],
                flags=cy.flags + list(px.flags),
                **px.fields(),
            )
        )
    sun_through_final_yaws(sst.sun, views, final, cues, ph.ephemeris, heading_p, s)
    scene_flags = clock_doubts(scene_flags, photo_clock, far, sst.sun, probes)
    flag_doubtful_yaws(sst.sun, probes, ph.camera_probe)
    explain_rejections(sst.sun, sst.outranked, probes)
    for v, cs in zip(views, sst.sun.captures):  # per-capture sun directions back into the sun-frame product's frame
        _capture_sun_to_product_frame(cs, v.C)
    sa = SceneAlignment(
        id=scene.id, photo=photo, camera_probe=ph.camera_probe, sun=sst.sun, probes=probes, flags=scene_flags
    )
    return sa, {"yaw_sigma": yaw_sigma}


# --------------------------------------------------------------------------- the campaign
def align_campaign(
    campaign_dir: str | os.PathLike,
    *,
    settings: AlignSettings | None = None,
    scenes: list[str] | None = None,
    labels: bool = True,
    report: bool = True,
    label_kinds: tuple[str, ...] | None = None,
    write: bool = True,
    log: Callable[[str], None] = lambda s: None,
    wait: bool = False,
) -> CampaignAlignment:
    """Align every scene of an ingested campaign (module doc); returns and writes ``align/alignment.json``.

    ``label_kinds``: which automatic labels to put into the store (default all: sun, sun_scene,
    heading, probe_pixel); ``write=False`` writes no alignment file (``solidkit label sun``). Computed
    with the BLAS libraries on one thread (:func:`solidkit.threads.deterministic`): the same bytes
    whatever the machine's thread count. Runs as the campaign's only writer
    (:func:`solidkit.capture.lock.campaign_lock`: another step running refuses it, or ``wait``).
    """
    if not Path(campaign_dir, "manifest.json").is_file():
        raise InputError(f"{campaign_dir}: not an ingested campaign (no manifest.json)")
    with campaign_lock(campaign_dir, "align" if write else "label sun", wait=wait, log=log), deterministic():
        return _align_campaign(
            campaign_dir,
            settings=settings,
            scenes=scenes,
            labels=labels,
            report=report,
            label_kinds=label_kinds,
            write=write,
            log=log,
        )


def _align_campaign(
    campaign_dir: str | os.PathLike,
    *,
    settings: AlignSettings | None,
    scenes: list[str] | None,
    labels: bool,
    report: bool,
    label_kinds: tuple[str, ...] | None,
    write: bool,
    log: Callable[[str], None],
) -> CampaignAlignment:
    campaign = Path(campaign_dir)
    if not (campaign / "manifest.json").is_file():
        raise InputError(f"{campaign}: not an ingested campaign (no manifest.json)")
    manifest = load_manifest(campaign)
    if not manifest.scenes:
        raise InputError(f"{campaign}: the manifest has no scenes")
    wanted = set(scenes or [sc.id for sc in manifest.scenes])
    unknown = wanted - {sc.id for sc in manifest.scenes}
    if unknown:
        raise InputError(f"unknown scene(s): {', '.join(sorted(unknown))}")
    s = settings or AlignSettings()
    store = None
    if labels:
        store = LabelStore(campaign)
    previous = None
    if (campaign / ALIGNMENT_FILE).is_file():
        try:
            previous = load_alignment(campaign)
        except SolidkitError:
            previous = None
    out = CampaignAlignment(
        solidkit_version=__version__, manifest_sha256=sha256_file(campaign / "manifest.json"), settings=s.to_json()
    )
    extras = {}
    for sc in manifest.scenes:
        if sc.id not in wanted:
            if previous is not None:
                try:
                    out.scenes.append(previous.scene(sc.id))
                except KeyError:
                    pass
            continue
        log(f"{sc.id}: aligning")
        try:
            sa, extra = align_scene(campaign, manifest, sc, s, store, log)
            if s.products:
                write_products(campaign, manifest, sc, sa, s, previous, log)
        except Exception as exc:  # one scene's failure never discards the others
            sa, extra = failed_scene(sc, exc), {}
            log(f"{sc.id}: alignment failed, the other scenes are kept: {sa.flags[0]}")
            if os.environ.get("SOLIDKIT_DEBUG"):
                log(traceback.format_exc())
        out.scenes.append(sa)
        extras[sc.id] = extra
        if store is not None:
            _write_labels(store, sa, label_kinds)
    if write:
        save_alignment(out, campaign)
    if report and write:
        write_report(campaign, manifest, out)
    return out


def failed_scene(scene: Scene, exc: BaseException) -> SceneAlignment:
    """The record of a scene whose alignment raised ``exc``: no photo, probes or sun, flagged ``align_failed`` with
    the error (the test set leaves it out, saying why)."""
    what = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if not isinstance(exc, SolidkitError):
        what = f"{type(exc).__name__}: {what}"
    return SceneAlignment(
        id=scene.id,
        photo=None,
        camera_probe=camera_probe_of(scene),
        sun=SceneSun(found=False),
        flags=[str(Flag(FlagCode.ALIGN_FAILED, what))],
    )


def _write_labels(store: Any, sa: SceneAlignment, kinds: tuple[str, ...] | None = None) -> None:
    """Auto labels (C2): sun per capture, sun_scene, heading per capture, probe_pixel from geometry."""
    kinds = kinds or ("sun", "sun_scene", "heading", "probe_pixel")
    for cs in sa.sun.captures if "sun" in kinds else []:
        if cs.source != "auto":
            continue
        value: dict[str, Any] = {
            "found": cs.found,
            "azimuth_deg": cs.azimuth_deg,
            "elevation_deg": cs.elevation_deg,
            "uncertainty_deg": cs.uncertainty_deg,
            "candidates": [
                c.model_dump(include={"azimuth_deg", "elevation_deg", "size_deg", "chosen", "reasons"})
                for c in cs.candidates
            ],
        }
        store.put("sun", f"{sa.id}/{cs.probe}", value, source="auto", annotator=ANNOTATOR, flags=_flag_names(cs.flags))
    sun = sa.sun
    if "sun_scene" in kinds:
        store.put(
            "sun_scene",
            sa.id,
            {
                "found": sun.found and sun.azimuth_deg is not None,
                "azimuth_deg": sun.azimuth_deg if sun.found else None,
                "elevation_deg": sun.elevation_deg if sun.found and sun.azimuth_deg is not None else None,
                "uncertainty_deg": sun.uncertainty_deg,
            },
            source="auto",
            annotator=ANNOTATOR,
            flags=_flag_names(sun.flags),
        )
    for pa in sa.probes:
        if "heading" in kinds and pa.yaw_deg is not None and pa.yaw_source == "auto":
            store.put(
                "heading",
                f"{sa.id}/{pa.id}",
                {"yaw_deg": pa.yaw_deg, "residual_deg": pa.residual_deg},
                source="auto",
                annotator=ANNOTATOR,
                flags=_flag_names(pa.flags),
            )
        if "probe_pixel" in kinds and pa.pixel_source == "geometry" and pa.pixel_full is not None:
            store.put(
                "probe_pixel",
                f"{sa.id}/{pa.id}",
                {"x": max(pa.pixel_full[0], -0.5), "y": max(pa.pixel_full[1], -0.5)},
                source="auto",
                annotator=ANNOTATOR,
                flags=_flag_names(pa.flags),
            )


def _flag_names(flags: list[str]) -> list[str]:
    """Store flags are names: the code of each flag (:class:`~solidkit.flags.Flag`), each once."""
    names = []
    for code in flag_codes(flags):
        n = re.sub(r"[^A-Za-z0-9_.-]", "_", code)[:64]
        if n and n not in names:
            names.append(n)
    return names
