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
hash), and the label store ignores identical puts.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from solidkit.align.captures import (Capture, camera_probe_of, captures_of, levelling_of, load_normal_panorama,
                                     photo_shot_of, read_hdr, read_sun_frame)
from solidkit.align.ephemeris import capture_place, ephemeris_for
from solidkit.align.features import Features, panorama_features, photo_features
from solidkit.align.heading import PhotoMatch, feature_cue, fuse_cues, match_photo
from solidkit.align.schema import (ALIGNMENT_FILE, CampaignAlignment, CaptureSun, Cue, Levelling, PhotoInfo,
                                   ProbeAlignment, SceneAlignment, SceneSun, body_to_pano, load_alignment,
                                   save_alignment, wrap_deg)
from solidkit.align.sun import Blob, CaptureSunInput, SunSettings, find_candidates, scene_sun, sky_fraction
from solidkit.capture.manifest import Manifest, Scene, load_manifest
from solidkit.envmap.coords import (angles_from_direction, angular_distance, direction_from_angles, rotation_from_ypr,
                                    ypr_from_rotation)
from solidkit.envmap.io import srgb_decode
from solidkit.errors import InputError, SolidkitError
from solidkit.flags import flag_codes
from solidkit.fsutil import atomic_path, sha256_file

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


def _feature_panorama(campaign: Path, manifest: Manifest, cap: Capture) -> tuple[np.ndarray | None, bool, str, list[str]]:
    """(level panorama for features, is_linear, description, input hashes)."""
    if cap.hdr_path:  # keyed by the product's content: a rebuilt or replaced product is new input
        return read_hdr(campaign, cap.hdr_path), True, cap.hdr_path, [sha256_file(campaign / cap.hdr_path)]
    if cap.normal is not None:
        return load_normal_panorama(campaign, manifest, cap.normal), False, cap.normal.original, [cap.normal.sha256]
    return None, False, "", []


# --------------------------------------------------------------------------- photo
def _photo_info(campaign: Path, manifest: Manifest, scene: Scene) -> tuple[PhotoInfo | None, list[str]]:
    from solidkit.calibration.camera import IntrinsicsError, intrinsics_from_exif, intrinsics_from_fov
    from solidkit.camera.metadata import CaptureMetadata

    flags: list[str] = []
    shot = photo_shot_of(manifest, scene)
    if shot is None:
        return None, ["no_photo: the scene has no photo"]
    meta = CaptureMetadata.model_validate(shot.metadata)
    try:
        K, source = intrinsics_from_exif(meta)
    except IntrinsicsError as exc:
        K, source = intrinsics_from_fov(meta.width, meta.height, math.radians(60.0)), "assumed-hfov-60"
        flags.append(f"no_intrinsics: {exc}; a 60 deg field of view is assumed")
    heading = getattr(scene, "photo_heading_deg", None)
    if heading is None:
        heading = (shot.metadata.get("gps") or {}).get("img_direction_deg")
    pitch, roll = getattr(scene, "photo_pitch_deg", None), getattr(scene, "photo_roll_deg", None)
    from solidkit.align.ephemeris import capture_time

    when, _ = capture_time(shot.metadata)
    info = PhotoInfo(path=shot.original, sha256=shot.sha256, size=[meta.width, meta.height], K_full=np.asarray(K).tolist(),
                     K_source=source, pitch_deg=pitch, roll_deg=roll, heading_deg=heading,
                     pitch_roll_source="exif" if pitch is not None and roll is not None else "",
                     time=None if when is None else when.isoformat())
    if heading is None:
        flags.append("no_photo_heading: no compass heading for the photo (GPSImgDirection); world azimuths unknown")
    return info, flags


# --------------------------------------------------------------------------- the scene
@dataclass
class _CapState:
    cap: Capture
    pitch: float = 0.0
    roll: float = 0.0
    heading: float | None = None
    features: Features | None = None
    feature_src: str = ""
    normal_lin: np.ndarray | None = None
    blobs: list[Blob] = field(default_factory=list)
    cues: dict[str, Cue] = field(default_factory=dict)
    fit: Any = None
    flags: list[str] = field(default_factory=list)
    ephemeris: Any = None
    C: np.ndarray = field(default_factory=lambda: np.eye(3))  # product's level frame -> refined level frame
    tilt: Any = None
    link_flags: list[str] = field(default_factory=list)
    linear: bool = False  # normal_lin from an HDR product (else a decoded LDR shot, clipped at 1)


def align_scene(campaign: Path, manifest: Manifest, scene: Scene, settings: AlignSettings, store: Any = None,
                log: Callable[[str], None] = lambda s: None) -> tuple[SceneAlignment, dict[str, Any]]:
    """Align one scene (module doc). Returns the scene's alignment and per-capture working data
    (``{"yaw_sigma": {probe: deg}}``) for the products and report."""
    photo, scene_flags = _photo_info(campaign, manifest, scene)
    caps = [_CapState(c) for c in captures_of(manifest, scene)]
    cam_id = camera_probe_of(scene)
    if cam_id is None:
        scene_flags.append("no_camera_position: no capture is marked as taken at the photo camera's position")
    photo_shot = photo_shot_of(manifest, scene)
    photo_place = capture_place(photo_shot.metadata) if photo_shot is not None else None
    photo_eph = ephemeris_for(photo_shot.metadata) if photo_shot is not None else None
    heading_p = photo.heading_deg if photo is not None else None

    # features
    s = settings
    for st in caps:
        ref = st.cap.normal
        if ref is not None:
            st.pitch, st.roll, _ = levelling_of(ref)
            st.heading = ref.metadata.get("heading_deg")
            st.ephemeris = ephemeris_for(ref.metadata, photo_place)
        else:
            st.flags.append("no_normal_shot: no single exposure to make the LDR probe from")
        pano, linear, src, inputs = _feature_panorama(campaign, manifest, st.cap)
        if pano is None:
            st.flags.append("no_panorama: neither an HDR product nor a normal shot")
            continue
        key = _cache_key("pano", inputs, src, s.feature_fov_deg, list(s.feature_pitches_deg), linear, 2)
        st.features = _cached(campaign, key, lambda: panorama_features(
            pano, fov_deg=s.feature_fov_deg, pitches_deg=s.feature_pitches_deg, linear=linear))
        st.feature_src = src
        st.normal_lin = pano if linear else srgb_decode(pano.astype(np.float32) / 255.0)
        st.linear = linear
        if s.refine_levelling:
            _refine_levelling(st, pano, s)
            f = st.features
            st.features = Features(f.directions @ st.C.T, f.descriptors, f.pixels, f.sizes)
        log(f"{scene.id}/{st.cap.id}: {len(st.features)} features"
            + ("" if st.tilt is None else f", residual tilt {st.tilt.tilt_deg:.2f} deg ({'reliable' if st.tilt.reliable else 'unreliable'})"))

    if photo_eph is not None:
        from solidkit.align.sun import _hours_apart

        far = [st.cap.id for st in caps if st.ephemeris is not None and _hours_apart(photo_eph, st.ephemeris) > 1.0]
        if far:
            scene_flags.append(f"clock_mismatch: {', '.join(far)} taken more than an hour from the photo "
                               "(camera clocks or UTC offsets disagree); no sun drift correction there")
    by_id = {st.cap.id: st for st in caps}
    cam = by_id.get(cam_id) if cam_id else None
    photo_match: PhotoMatch | None = None
    pf: Features | None = None
    if cam is not None and cam.features is not None and photo is not None:
        from solidkit.envmap.io import read_ldr

        img = read_ldr(campaign / photo.path)
        K = np.asarray(photo.K_full)
        # SIFT at the panorama's angular resolution: photo pixels per radian -> panorama's (H / pi)
        scale = s.photo_scale or min(1.0, (_pano_height(cam) / math.pi) / K[0, 0] * 1.1)
        pf = _cached(campaign, _cache_key("photo", photo.sha256, photo.K_full, scale, 2),
                     lambda: photo_features(img, K, scale=scale))
        photo_match, detail = match_photo(pf, cam.features, K=K, refine_f=s.refine_focal, ratio=s.match_ratio)
        if photo_match is not None and photo_match.focal_scale != 1.0:
            Kr = K.copy()
            Kr[0, 0] *= photo_match.focal_scale
            Kr[1, 1] *= photo_match.focal_scale
            if abs(photo_match.focal_scale - 1.0) > s.focal_tolerance:
                scene_flags.append(f"focal_refined: the EXIF focal length was {100 * (photo_match.focal_scale - 1):+.1f}% off "
                                   f"({photo.K_source}); K refined from the camera-position panorama")
            photo.K_full, photo.K_source = Kr.tolist(), f"{photo.K_source}+features"
        if photo_match is not None:
            cam.cues["photo_features"] = Cue(yaw_deg=photo_match.yaw_deg, sigma_deg=photo_match.sigma_deg, ok=True,
                                             detail=detail + f"; photo pitch {photo_match.pitch_deg:+.2f}, "
                                                             f"roll {photo_match.roll_deg:+.2f} deg")
            if photo.pitch_deg is not None and photo.roll_deg is not None:
                d = max(abs(photo.pitch_deg - photo_match.pitch_deg), abs(photo.roll_deg - photo_match.roll_deg))
                if d > 1.0:
                    scene_flags.append(f"photo_pose_disagrees: recorded pitch/roll {photo.pitch_deg:+.2f}/{photo.roll_deg:+.2f},"
                                       f" features {photo_match.pitch_deg:+.2f}/{photo_match.roll_deg:+.2f} deg")
            if photo.pitch_deg is None or photo.roll_deg is None or photo_match.n_inliers >= s.min_pose_inliers:
                # the rotation to a levelled panorama measures the photo's pitch and roll better than a bubble level
                photo.pitch_deg, photo.roll_deg = photo_match.pitch_deg, photo_match.roll_deg
                photo.pitch_roll_source = "features"
        else:
            cam.cues["photo_features"] = Cue(yaw_deg=None, ok=False, detail=detail)
            scene_flags.append(f"photo_match_failed: {detail}")
    if photo is not None and (photo.pitch_deg is None or photo.roll_deg is None):
        photo.pitch_deg, photo.roll_deg, photo.pitch_roll_source = 0.0, 0.0, "assumed_zero"
        scene_flags.append("photo_pose_unknown: pitch and roll assumed zero")

    # compass cues
    for st in caps:
        if st.heading is not None and heading_p is not None:
            st.cues["compass"] = Cue(yaw_deg=wrap_deg(float(st.heading) - float(heading_p)), sigma_deg=s.sun.compass_sigma_deg,
                                     ok=True, detail=f"Theta heading {float(st.heading):.1f} deg - photo heading "
                                                     f"{float(heading_p):.1f} deg")
        else:
            st.cues["compass"] = Cue(yaw_deg=None, ok=False, detail="no compass heading")

    # features vs the camera position
    pre = fuse_cues({k: c.model_copy() for k, c in cam.cues.items()}) if cam is not None else None
    yaw_cam = pre.yaw_deg if pre is not None else None
    yaw_cam_sigma = pre.sigma_deg if pre is not None and pre.sigma_deg is not None else 0.0
    for st in caps:
        if st is cam or cam is None or cam.features is None:
            continue
        if st.features is None:
            st.cues["features"] = Cue(yaw_deg=None, ok=False, detail="features failed: no panorama")
            continue
        cue, fit = feature_cue(cam.features, st.features, yaw_cam, yaw_cam_sigma, level_sigma_deg=s.sun.level_sigma_deg,
                               max_baseline_elevation_deg=s.max_baseline_elevation_deg, ratio=s.match_ratio)
        st.cues["features"], st.fit = cue, fit

    # the sun
    # yaws for the sun's cross-position test: from features only; a compass-only capture is tested on
    # elevation (its compass may be 90 deg off: then the sun gives its yaw and the compass is flagged)
    pre_yaw = {}
    for st in caps:
        f = fuse_cues({k: c.model_copy() for k, c in st.cues.items() if k != "compass"})
        pre_yaw[st.cap.id] = (f.yaw_deg, f.sigma_deg)
    inputs = []
    for st in caps:
        human = _human_sun(store, scene.id, st.cap.id)
        if st.cap.sun_frame_path:
            frame = read_sun_frame(campaign, st.cap.sun_frame_path)
            st.blobs = find_candidates(frame, saturation=s.sun.saturation, max_candidates=s.sun.max_candidates)
            if st.normal_lin is not None:
                dirs = [b.direction for b in st.blobs]
                st.blobs = [Blob(**{**b.__dict__, "sky_fraction": sky_fraction(
                    st.normal_lin, b.direction, exclude=[d for d in dirs if d is not b.direction])}) for b in st.blobs]
            st.blobs = [_to_frame(b, st.C) for b in st.blobs]
            note = ""
        else:
            note = "no sun frame (no low-exposure shot at this position)"
        if human is not None and human.found:
            d = st.C @ direction_from_angles(math.radians(human.azimuth_deg), math.radians(human.elevation_deg))
            az, el = (math.degrees(float(v)) for v in angles_from_direction(d))
            human = human.model_copy(update={"azimuth_deg": wrap_deg(az), "elevation_deg": el})
        y, ys = pre_yaw[st.cap.id]
        compass = st.cues.get("compass")
        inputs.append(CaptureSunInput(st.cap.id, st.blobs, st.ephemeris, y, ys, st.heading, note, human,
                                      compass_yaw_deg=None if compass is None else compass.yaw_deg))
    sun, _, sun_moves = _sun_with_motion(caps, inputs, photo_eph, heading_p, s)

    # captures whose features failed against the camera position: features against the other captures,
    # whose yaws (features, sun; never the compass) carry them over
    _chain_cues(caps, cam, s)
    if s.manhattan:
        _manhattan_cues(caps, s, photo_lines=lambda: _photo_lines(campaign, photo))
    if s.links:
        _link_cues(caps, s, sun_moves, log)

    # final yaws, probe pixels
    probes: list[ProbeAlignment] = []
    yaw_sigma: dict[str, float | None] = {}
    for st in caps:
        fused = fuse_cues(st.cues)
        flags = list(st.flags) + fused.flags
        yaw, source = fused.yaw_deg, "auto"
        label = _human(store, "heading", f"{scene.id}/{st.cap.id}")
        if label is not None:
            lyaw = float(label.value["yaw_deg"])
            st.cues["label"] = Cue(yaw_deg=lyaw, ok=True, weight=1.0, detail=f"{label.source} label by {label.annotator}",
                                   residual_deg=None if yaw is None else wrap_deg(lyaw - yaw))
            if yaw is not None and abs(wrap_deg(lyaw - yaw)) > 2.0:
                flags.append(f"label_differs: the {label.source} heading is {wrap_deg(lyaw - yaw):+.1f} deg from the cues")
            yaw, source = lyaw, label.source
        if "features" in st.cues and not st.cues["features"].ok and st.cues["features"].yaw_deg is None and yaw is not None:
            used = [k for k, c in st.cues.items() if c.ok and k != "features"]
            flags.append(f"features_failed: no match to the camera position; yaw from {', '.join(used) or 'nothing'}")
        if "manhattan" in st.cues and st.cues["manhattan"].ok and source == "auto":
            flags.append("yaw_from_street_lines: only the street's line directions (modulo 90 deg, quadrant from the "
                         "compass) fix this yaw: review")
        if "linked" in st.cues and st.cues["linked"].ok and source == "auto":
            flags.extend(st.link_flags)
        yaw_sigma[st.cap.id] = fused.sigma_deg
        role = "camera" if st.cap.id == cam_id else "probe"
        levelling, y0 = _levelling_record(st)
        if yaw is not None and source == "auto":
            yaw = wrap_deg(yaw + y0)  # R_y(yaw) C R_meta = R_y(yaw + y0) R(0, p, r)
        pa = ProbeAlignment(
            id=st.cap.id, role=role, levelling=levelling,
            rotation=body_to_pano(yaw if yaw is not None else 0.0, levelling.pitch_deg, levelling.roll_deg).tolist(),
            yaw_deg=yaw, yaw_source=source, residual_deg=fused.residual_deg,
            yaw_sigma_deg=fused.sigma_deg if source == "auto" else None, cues=st.cues, flags=flags)
        if role == "probe" and photo is not None:
            _probe_pixel(pa, st, scene, store, photo, cam, yaw_cam if yaw_cam is not None else None, s)
        probes.append(pa)
    _explain_rejections(sun, probes)
    for st, cs in zip(caps, sun.captures):  # per-capture sun directions back into the sun-frame product's frame
        _capture_sun_to_product_frame(cs, st.C)
    sa = SceneAlignment(id=scene.id, photo=photo, camera_probe=cam_id, sun=sun, probes=probes, flags=scene_flags)
    return sa, {"yaw_sigma": yaw_sigma}


def _sun_with_motion(caps: list[_CapState], inputs: list[CaptureSunInput], photo_eph: Any, heading_p: float | None,
                     s: AlignSettings) -> tuple[SceneSun, str, bool]:
    """The scene's sun and the captures' sun cues, with the sun moving (ephemeris drift between the
    captures' times) or static, as ``s.sun_motion`` says; ``"auto"`` lets the images decide.

    Evidence for "auto": how well the sun cues agree with the captures' non-sun yaw cues
    (features), and how well the captures' sun elevations agree, under each hypothesis
    (chi-square with the cues' sigmas). The physical default (moving) stands without evidence.
    """
    from dataclasses import replace

    modes = {"ephemeris": [True], "static": [False], "auto": [True, False]}[s.sun_motion]
    results = {}
    for moves in modes:
        ss = replace(s, sun=replace(s.sun, sun_moves=moves))
        for st in caps:
            st.cues.pop("sun", None)
        sun = scene_sun(inputs, photo_ephemeris=photo_eph, photo_heading_deg=heading_p, settings=ss.sun)
        _sun_cues(caps, sun, photo_eph, ss, heading_p)
        chi2, n = 0.0, 0
        for st in caps:
            sc = st.cues.get("sun")
            others = {k: c.model_copy() for k, c in st.cues.items() if k in ("features", "photo_features")}
            if sc is None or sc.yaw_deg is None or not others:
                continue
            f = fuse_cues(others)
            if f.yaw_deg is None:
                continue
            r = wrap_deg(sc.yaw_deg - f.yaw_deg)
            chi2 += r**2 / ((sc.sigma_deg or 1.0) ** 2 + (f.sigma_deg or 1.0) ** 2)
            n += 1
        # the elevations of one sun seen from every position agree (no yaw involved)
        els = [(cs.elevation_deg, st) for st, cs in zip(caps, sun.captures) if cs.found]
        if len(els) >= 2:
            from solidkit.align.sun import _sun_in_photo_time

            moved = [_sun_in_photo_time(Blob(np.zeros(3), 0.0, e, 0.0, 0, 0.0), CaptureSunInput(st.cap.id, [], st.ephemeris),
                                        photo_eph, ss.sun)[1] for e, st in els]
            sig_el = math.hypot(s.sun.level_sigma_deg, s.sun.centroid_sigma_deg)
            chi2 += float(np.sum((np.array(moved) - np.mean(moved)) ** 2)) / sig_el**2
            n += len(els) - 1
        results[moves] = (chi2, n, sun, {st.cap.id: st.cues.get("sun") for st in caps})
    if len(results) == 1 or min(r[1] for r in results.values()) < 2 or photo_eph is None:
        moves = modes[0]
        why = f"sun motion: {'ephemeris drift applied' if moves else 'static'} ({s.sun_motion})"
    else:
        moves = results[True][0] <= results[False][0]
        why = (f"sun motion: {'moving (ephemeris drift applied)' if moves else 'static (no drift between captures)'}"
               f", chosen by the images: chi2 {results[True][0]:.1f} moving vs {results[False][0]:.1f} static "
               f" ({results[True][1]} comparisons: sun vs feature yaws, sun elevations)")
    chi2, n, sun, cues = results[moves]
    for st in caps:
        if cues[st.cap.id] is not None:
            st.cues["sun"] = cues[st.cap.id]
    sun.motion = why
    return sun, why, bool(moves)


def _explain_rejections(sun: SceneSun, probes: list[ProbeAlignment]) -> None:
    """Candidates rejected only because another one fitted better (their capture's yaw was not known when
    the sun was chosen: elevation alone, e.g. a glint in a vertical glass wall) get the reason the final
    yaw gives: how far from the scene's sun they are in the photo's panorama frame."""
    if not sun.found or sun.azimuth_deg is None:
        return
    yaws = {p.id: p.yaw_deg for p in probes}
    for cs in sun.captures:
        yaw = yaws.get(cs.probe)
        if yaw is None:
            continue
        for c in cs.candidates:
            if c.reasons == ["another candidate fits better"]:
                d_az = wrap_deg(c.azimuth_deg + yaw - sun.azimuth_deg)
                d = math.degrees(float(angular_distance(
                    direction_from_angles(math.radians(c.azimuth_deg + yaw), math.radians(c.elevation_deg)),
                    direction_from_angles(math.radians(sun.azimuth_deg), math.radians(sun.elevation_deg)))))
                c.reasons = [f"not where the scene's sun is: {d:.1f} deg away (azimuth {d_az:+.1f} deg) once this capture's "
                             "yaw is known; same elevation as the sun: a mirror image (glint) in a vertical glass wall?"
                             if abs(c.elevation_deg - (cs.elevation_deg or c.elevation_deg)) < 1.5 else
                             f"not where the scene's sun is: {d:.1f} deg away once this capture's yaw is known"]
                c.scores["distance_to_scene_sun_deg"] = d


def _chain_cues(caps: list[_CapState], cam: _CapState | None, s: AlignSettings) -> None:
    """``features_via_<id>`` cues for captures left with the compass alone (features failed against the
    camera position, no sun): a chain adds the other capture's error, so it is a fallback only."""
    known = {}
    for st in caps:
        f = fuse_cues({k: c.model_copy() for k, c in st.cues.items() if k != "compass"})
        if f.yaw_deg is not None:
            known[st.cap.id] = (f.yaw_deg, f.sigma_deg or 0.0, st)
    for st in caps:
        own, sun = st.cues.get("features"), st.cues.get("sun")
        if st is cam or st.features is None or own is None or own.yaw_deg is not None or (sun is not None and sun.ok):
            continue
        for oid, (yaw_o, sig_o, other) in known.items():
            if other is st or other is cam or other.features is None:
                continue
            cue, _ = feature_cue(other.features, st.features, yaw_o, sig_o, level_sigma_deg=s.sun.level_sigma_deg,
                                 max_baseline_elevation_deg=s.max_baseline_elevation_deg, ratio=s.match_ratio)
            if cue.yaw_deg is not None:
                cue.detail = cue.detail.replace("the camera position", oid)
                st.cues[f"features_via_{oid}"] = cue


def _non_compass(st: _CapState) -> Any:
    """The fusion of a capture's yaw cues other than its compass."""
    return fuse_cues({k: c.model_copy() for k, c in st.cues.items() if k != "compass" and c.yaw_deg is not None})


def _compass_only(st: _CapState) -> bool:
    """True when the compass is the only cue that gives the capture a yaw."""
    compass = st.cues.get("compass")
    return compass is not None and compass.yaw_deg is not None and _non_compass(st).yaw_deg is None


def _link_cues(caps: list[_CapState], s: AlignSettings, sun_moves: bool = False,
               log: Callable[[str], None] = lambda s: None) -> None:
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
    from solidkit.align.links import GROUND, Link, solve_links
    from solidkit.align.sky import relative_sky_yaw, sky_layer, without_sun_drift
    from solidkit.align.sun import _hours_apart

    lone = [st for st in caps if st.features is not None and _compass_only(st)]
    if not lone:
        return
    known = {}
    for st in caps:
        if st.features is not None and st not in lone:
            f = _non_compass(st)
            if f.yaw_deg is not None:
                street = "manhattan" in st.cues and st.cues["manhattan"].ok and len([c for k, c in st.cues.items()
                                                                                      if c.ok and k != "compass"]) == 1
                known[st.cap.id] = (f.yaw_deg, f.sigma_deg or 0.0, street)
    sky = {}
    if s.sky:
        from solidkit.envmap.resample import rotate

        for st in caps:
            if st.normal_lin is not None and (st in lone or st.cap.id in known):
                lin = np.asarray(st.normal_lin, np.float32)
                small = rotate(lin, st.C, "linear", 512) if not np.allclose(st.C, np.eye(3)) else lin
                sky[st.cap.id] = sky_layer(small, saturation=None if st.linear else 0.98)
    links: list[Link] = []
    lone_ids = [st.cap.id for st in lone]
    pairs = [(a, b) for i, a in enumerate(caps) for b in caps[i + 1:]
             if (a in lone or b in lone) and (a.cap.id in known or a in lone) and (b.cap.id in known or b in lone)]
    for a, b in pairs:
        if b.cap.id not in lone_ids:
            a, b = b, a  # b is lone
        rel = []
        cue, fit = feature_cue(a.features, b.features, 0.0, 0.0, level_sigma_deg=s.sun.level_sigma_deg,
                               max_baseline_elevation_deg=s.max_baseline_elevation_deg, ratio=s.match_ratio)
        if cue.yaw_deg is not None:
            rel.append(("features", cue.yaw_deg, cue.sigma_deg, f"{fit.n_inliers} inliers"))
        if a.cap.id in sky and b.cap.id in sky:
            r, why = relative_sky_yaw(sky[a.cap.id], sky[b.cap.id], min_overlap=s.sky_min_overlap,
                                      correlation_px=s.sky_correlation_px, min_delta_chi2=s.sky_min_delta_chi2)
            if r is not None:
                drift, what = 0.0, f"sigma {r.sigma_deg:.2f} deg"
                if sun_moves and a.ephemeris is not None and b.ephemeris is not None and _hours_apart(a.ephemeris, b.ephemeris) <= 1.0:
                    drift = wrap_deg(b.ephemeris.azimuth_deg - a.ephemeris.azimuth_deg)
                    what += f", sun drift {drift:+.2f} deg applied"
                yaw = without_sun_drift(r.yaw_deg, 0.0, drift)
                rel.append(("sky", yaw, r.sigma_deg, what))
        for kind, yaw, sig, what in rel:
            if a.cap.id in known:
                ya, sa, street = known[a.cap.id]
                links.append(Link(GROUND, b.cap.id, wrap_deg(ya + yaw), math.hypot(sig, sa), f"{kind}_via_{a.cap.id}",
                                  f"{kind} {b.cap.id} to {a.cap.id} ({what})"
                                  f"{', whose yaw is from street lines' if street else ''}"))
            else:
                links.append(Link(a.cap.id, b.cap.id, yaw, sig, kind, f"{kind} {a.cap.id}-{b.cap.id} ({what})"))
        log(f"links {a.cap.id}-{b.cap.id}: " + (", ".join(f"{k} {y:+.2f}+-{g:.2f}" for k, y, g, _ in rel) or "none"))
    for st in lone:
        c = st.cues["compass"]
        links.append(Link(GROUND, st.cap.id, float(c.yaw_deg), float(c.sigma_deg or s.sun.compass_sigma_deg), "compass"))
    solved = solve_links(lone_ids, links)
    for st in lone:
        r = solved.get(st.cap.id)
        if r is None:
            st.cues["linked"] = Cue(yaw_deg=None, ok=False, detail="no feature or sky link to another capture")
            continue
        parts = [e.detail for e in r.used] + [e.detail for e in r.anchors]
        detail = "; ".join(dict.fromkeys(parts))
        if r.compasses:
            detail += f"; compasses of {', '.join(r.compasses)}"
        if r.rejected:
            detail += f"; inconsistent, left out: {', '.join(e.detail for e in r.rejected)}"
        st.cues["linked"] = Cue(yaw_deg=r.yaw_deg, sigma_deg=r.sigma_deg, ok=True, detail=detail)
        if not r.anchors:
            st.link_flags.append(f"yaw_from_compasses: the compasses of {', '.join(r.compasses)} linked by features or "
                                 "sky to this capture fix its yaw (no capture of known yaw in its group): review")
        elif all(e.kind.startswith("sky") for e in r.used + r.anchors):
            st.link_flags.append(f"yaw_from_sky: only the sky's radiance pattern ({len(r.used) + len(r.anchors)} sky "
                                 f"link(s), sigma {r.sigma_deg:.2f} deg) fixes this yaw beside the compass: review")
        elif all("street lines" in e.detail for e in r.anchors):
            st.link_flags.append("yaw_from_street_lines: linked to captures whose yaw only street lines fix "
                                 f"({', '.join(e.kind for e in r.anchors)}): review")


def _photo_lines(campaign: Path, photo: PhotoInfo | None) -> tuple[np.ndarray, np.ndarray] | None:
    """The photo's line segments as great-circle normals in its level panorama frame (its pitch/roll)."""
    if photo is None:
        return None
    from solidkit.align.manhattan import photo_line_normals
    from solidkit.envmap.io import read_ldr

    R = np.asarray(rotation_from_ypr(0.0, math.radians(photo.pitch_deg or 0.0), math.radians(photo.roll_deg or 0.0)))
    return photo_line_normals(read_ldr(campaign / photo.path), np.asarray(photo.K_full), R)


def _manhattan_cues(caps: list[_CapState], s: AlignSettings,
                    photo_lines: Callable[[], tuple[np.ndarray, np.ndarray] | None] | None = None) -> None:
    """``manhattan`` cues (:mod:`solidkit.align.manhattan`) for captures left with the compass alone.

    The street's horizontal vanishing azimuth in the photo's panorama frame (modulo 90°) comes from
    the captures whose yaw other cues fixed and from the photo itself (yaw 0 in its own frame; its
    pitch/roll level its lines): a robust mean over them. A lone capture's own vanishing azimuth
    then gives its yaw modulo 90°, the quadrant nearest to its compass.
    """
    from solidkit.align.manhattan import line_normals, vanishing_azimuth

    lone = [st for st in caps if st.normal_lin is not None and _compass_only(st)]
    if not lone:
        return
    fits = {}
    for st in caps:
        if st.normal_lin is not None:
            fits[st.cap.id] = vanishing_azimuth(*line_normals(st.normal_lin, linear=True, C=st.C))
    members = []
    for st in caps:
        f, known = fits.get(st.cap.id), _non_compass(st)
        if f is not None and known.yaw_deg is not None and f.ambiguity < 0.95:
            members.append(((f.azimuth_deg + known.yaw_deg) % 90.0, math.hypot(f.sigma_deg, known.sigma_deg or 0.0), st.cap.id))
    lines = photo_lines() if photo_lines is not None else None
    fp = vanishing_azimuth(*lines) if lines is not None else None
    if fp is not None and fp.ambiguity < 0.95:
        # the photo's pitch/roll (features or field notes) tilt its lines: a floor of 0.5 deg
        members.append((fp.azimuth_deg % 90.0, math.hypot(fp.sigma_deg, 0.5), "the photo"))
    if not members:
        for st in lone:
            st.cues["manhattan"] = Cue(yaw_deg=None, ok=False, detail="neither the photo nor a capture with a known yaw shows the street's lines")
        return

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
    for st in lone:
        f = fits.get(st.cap.id)
        if f is None or f.ambiguity > s.manhattan_max_ambiguity:
            why = "too few line segments" if f is None else f"no clear street direction (ambiguity {f.ambiguity:.2f})"
            st.cues["manhattan"] = Cue(yaw_deg=None, ok=False, detail=f"manhattan: {why}")
            continue
        compass = float(st.cues["compass"].yaw_deg)
        base = ref - f.azimuth_deg
        yaw = wrap_deg(base + 90.0 * round((compass - base) / 90.0))
        sigma = math.hypot(f.sigma_deg, ref_sigma, s.manhattan_model_sigma_deg)
        st.cues["manhattan"] = Cue(
            yaw_deg=yaw, sigma_deg=sigma, ok=True,
            detail=(f"street lines at {f.azimuth_deg:.2f} deg (mod 90) here vs {ref:.2f} deg in the photo frame "
                    f"(from {', '.join(m[2] for m in members)}); quadrant from the compass ({f.n_segments} segments)"))


def _refine_levelling(st: _CapState, pano: np.ndarray, s: AlignSettings) -> None:
    """Correct the metadata levelling by the panorama's residual tilt (vertical edges), weighting
    both by their uncertainties (small angles: each tilt component is a weighted mean of the
    metadata's 0 and the edges' estimate)."""
    from solidkit.envmap.tilt import residual_tilt

    try:
        est = residual_tilt(pano)
    except SolidkitError:
        return
    st.tilt = est
    if not est.reliable:
        return
    w = s.sun.level_sigma_deg**2 / (s.sun.level_sigma_deg**2 + max(est.uncertainty_deg, 0.05) ** 2)
    st.C = np.asarray(rotation_from_ypr(0.0, math.radians(w * est.pitch_deg), math.radians(w * est.roll_deg)))


def _levelling_record(st: _CapState) -> tuple[Levelling, float]:
    """The capture's levelling (body -> refined level frame) and the tiny yaw ``y0`` that composing
    the correction with the metadata's levelling leaves: ``C R(0, p_m, r_m) = R(y0, p, r)``."""
    if st.cap.normal is None:
        return Levelling(pitch_deg=0.0, roll_deg=0.0, source="none"), 0.0
    R = st.C @ np.asarray(rotation_from_ypr(0.0, math.radians(st.pitch), math.radians(st.roll)))
    y0, p, r = (math.degrees(float(v)) for v in ypr_from_rotation(R))
    t = st.tilt
    refined = not np.allclose(st.C, np.eye(3))
    lev = Levelling(pitch_deg=p, roll_deg=r, source="metadata+tilt" if refined else "metadata",
                    metadata_pitch_deg=st.pitch, metadata_roll_deg=st.roll,
                    residual_tilt_deg=None if t is None else t.tilt_deg,
                    tilt_uncertainty_deg=None if t is None else t.uncertainty_deg,
                    tilt_reliable=None if t is None else t.reliable,
                    confidence=None if t is None or not t.reliable else float(1.0 / (1.0 + t.uncertainty_deg)))
    return lev, y0


def _to_frame(b: Blob, C: np.ndarray) -> Blob:
    d = C @ b.direction
    az, el = (math.degrees(float(v)) for v in angles_from_direction(d))
    return Blob(**{**b.__dict__, "direction": d, "azimuth_deg": wrap_deg(az), "elevation_deg": el})


def _capture_sun_to_product_frame(cs: CaptureSun, C: np.ndarray) -> None:
    """Directions of a capture's sun result from the refined level frame back to its sun-frame product's."""
    if np.allclose(C, np.eye(3)):
        return

    def back(az: float, el: float) -> tuple[float, float]:
        d = C.T @ direction_from_angles(math.radians(az), math.radians(el))
        a, e = (math.degrees(float(v)) for v in angles_from_direction(d))
        return wrap_deg(a), e

    if cs.found:  # (a human label comes back to its own numbers)
        cs.azimuth_deg, cs.elevation_deg = back(cs.azimuth_deg, cs.elevation_deg)
    for c in cs.candidates:
        c.azimuth_deg, c.elevation_deg = back(c.azimuth_deg, c.elevation_deg)


def _pano_height(st: _CapState) -> int:
    return int(st.normal_lin.shape[0]) if st.normal_lin is not None else 960


def _sun_cues(caps: list[_CapState], sun: SceneSun, photo_eph: Any, s: AlignSettings, heading_p: float | None) -> None:
    """The ``sun`` cue: the scene's sun seen by the other captures (leave-one-out), minus this capture's."""
    from solidkit.align.sun import _sun_in_photo_time

    pts = {}
    for st, cs in zip(caps, sun.captures):
        if not cs.found:
            continue
        fake = Blob(np.zeros(3), cs.azimuth_deg, cs.elevation_deg, 0.0, 0, 0.0)
        inp = CaptureSunInput(st.cap.id, [], st.ephemeris)
        az, el = _sun_in_photo_time(fake, inp, photo_eph, s.sun)
        pts[st.cap.id] = (az, el, cs.uncertainty_deg or 0.1)
    for st, cs in zip(caps, sun.captures):
        if st.cap.id not in pts:
            st.cues["sun"] = Cue(yaw_deg=None, ok=False, detail=f"no sun here: {cs.reason}")
            continue
        az_c, el_c, unc_c = pts[st.cap.id]
        tilt = s.sun.level_sigma_deg * math.tan(math.radians(min(abs(el_c), 80.0)))
        own = math.hypot(unc_c / max(math.cos(math.radians(el_c)), 0.1), tilt)
        others = []
        for other in caps:
            if other is st or other.cap.id not in pts:
                continue
            y_other = other.cues and fuse_cues({k: c.model_copy() for k, c in other.cues.items() if k not in ("sun", "compass")})
            if y_other is None or y_other.yaw_deg is None:
                continue
            az_o, el_o, unc_o = pts[other.cap.id]
            sig_o = math.hypot(y_other.sigma_deg or 0.0, unc_o / max(math.cos(math.radians(el_o)), 0.1),
                               s.sun.level_sigma_deg * math.tan(math.radians(min(abs(el_o), 80.0))))
            others.append((wrap_deg(az_o + y_other.yaw_deg), sig_o, other.cap.id))
        if others:
            w = np.array([1.0 / max(o[1], 0.05) ** 2 for o in others])
            ang = np.radians([o[0] for o in others])
            az_p = math.degrees(math.atan2(float(np.sum(w * np.sin(ang))), float(np.sum(w * np.cos(ang)))))
            sig = math.hypot(1.0 / math.sqrt(w.sum()), own)
            st.cues["sun"] = Cue(yaw_deg=wrap_deg(az_p - az_c), sigma_deg=sig, ok=True,
                                 detail=f"sun azimuth {az_c:.2f} deg here vs {az_p:.2f} deg in the photo frame "
                                        f"(from {', '.join(o[2] for o in others)})")
        elif photo_eph is not None and heading_p is not None:
            az_p = wrap_deg(photo_eph.azimuth_deg - heading_p)
            st.cues["sun"] = Cue(yaw_deg=wrap_deg(az_p - az_c), sigma_deg=math.hypot(s.photo_compass_sigma_deg, own), ok=True,
                                 detail=f"sun azimuth {az_c:.2f} deg here vs the ephemeris {az_p:.2f} deg in the photo frame "
                                        "(through the photo's compass heading)")
        else:
            st.cues["sun"] = Cue(yaw_deg=None, ok=False, detail="the sun is seen here only, and there is no ephemeris")


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
    return CaptureSun(probe=pid, found=bool(v["found"]), azimuth_deg=v.get("azimuth_deg"), elevation_deg=v.get("elevation_deg"),
                      uncertainty_deg=v.get("uncertainty_deg"), reason=f"{lab.source} label by {lab.annotator}",
                      source=lab.source)


def _probe_pixel(pa: ProbeAlignment, st: _CapState, scene: Scene, store: Any, photo: PhotoInfo, cam: _CapState | None,
                 yaw_cam: float | None, s: AlignSettings) -> None:
    """Pixel of the probe in the photo (field notes > human label > geometry) and its geometric check."""
    from solidkit.envmap.coords import rotation_from_ypr

    geom = None
    if st.fit is not None and yaw_cam is not None and cam is not None and st.fit.t_support >= s.min_translation_support:
        d_lcam = st.fit.centre2_in_1
        d_p = np.asarray(rotation_from_ypr(math.radians(yaw_cam), 0.0, 0.0)) @ d_lcam
        R_cam = np.asarray(rotation_from_ypr(0.0, math.radians(photo.pitch_deg or 0.0), math.radians(photo.roll_deg or 0.0)))
        c = R_cam.T @ d_p
        if c[2] > 1e-6:
            p = np.asarray(photo.K_full) @ (c / c[2])
            geom = [float(p[0]), float(p[1])]
            pa.pixel_geometry_sigma_deg = math.degrees(st.fit.t_sigma) if math.isfinite(st.fit.t_sigma) else None
    pa.pixel_geometry = geom
    label = _human(store, "probe_pixel", f"{scene.id}/{pa.id}")
    if st.cap.probe.photo_pixel is not None:
        pa.pixel_full, pa.pixel_source = [float(v) for v in st.cap.probe.photo_pixel], "field_notes"
        if label is not None:
            pa.pixel_full, pa.pixel_source = [float(label.value["x"]), float(label.value["y"])], "label"
    elif label is not None:
        pa.pixel_full, pa.pixel_source = [float(label.value["x"]), float(label.value["y"])], "label"
    elif geom is not None:
        pa.pixel_full, pa.pixel_source = geom, "geometry"
        pa.flags.append("pixel_from_geometry: no marked pixel; the relative pose's direction is used (review)")
    else:
        pa.flags.append("no_pixel: no marked pixel and no relative pose with parallax to the camera position")
    w, h = photo.size
    if geom is not None and pa.pixel_full is not None and pa.pixel_source != "geometry":
        err = math.dist(geom, pa.pixel_full)
        pa.pixel_error_px = err
        from solidkit.align.features import rays_from_pixels

        r = rays_from_pixels(np.array([pa.pixel_full, geom]), np.asarray(photo.K_full))
        ang = math.degrees(float(angular_distance(r[0], r[1])))
        pa.pixel_error_deg = ang
        # tolerance: n_sigma of the baseline direction's own uncertainty (plus the lens's height above the marked
        # surface, ~1 deg at a few metres), never below pixel_tolerance_deg
        sig = pa.pixel_geometry_sigma_deg if pa.pixel_geometry_sigma_deg is not None else math.inf
        tol = max(s.pixel_tolerance_deg, s.pixel_n_sigma * math.hypot(sig, 1.0))
        # a pose from few matches can be wrong beyond its sigma (measured: 13 inliers in a glass scene, 11 deg off)
        if ang > tol and st.fit.n_inliers >= s.min_pixel_check_inliers:
            pa.flags.append(f"pixel_disagrees: the marked pixel is {ang:.1f} deg ({err:.0f} px) from the direction of the "
                            f"probe capture seen from the camera position ({geom[0]:.0f}, {geom[1]:.0f}; tolerance "
                            f"{tol:.1f} deg): wrong probe marked?")
    if pa.pixel_full is not None and not (-0.5 <= pa.pixel_full[0] <= w - 0.5 and -0.5 <= pa.pixel_full[1] <= h - 0.5):
        pa.flags.append("pixel_outside_photo")


# --------------------------------------------------------------------------- the campaign
def align_campaign(campaign_dir: str | os.PathLike, *, settings: AlignSettings | None = None, scenes: list[str] | None = None,
                   labels: bool = True, report: bool = True, label_kinds: tuple[str, ...] | None = None, write: bool = True,
                   log: Callable[[str], None] = lambda s: None) -> CampaignAlignment:
    """Align every scene of an ingested campaign (module doc); returns and writes ``align/alignment.json``.

    ``label_kinds``: which automatic labels to put into the store (default all: sun, sun_scene,
    heading, probe_pixel); ``write=False`` writes no alignment file (``solidkit label sun``).
    """
    from solidkit import __version__

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
        from solidkit.labeling.store import LabelStore

        store = LabelStore(campaign)
    previous = None
    if (campaign / ALIGNMENT_FILE).is_file():
        try:
            previous = load_alignment(campaign)
        except SolidkitError:
            previous = None
    out = CampaignAlignment(solidkit_version=__version__, manifest_sha256=sha256_file(campaign / "manifest.json"),
                            settings=s.to_json())
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
        sa, extra = align_scene(campaign, manifest, sc, s, store, log)
        if s.products:
            from solidkit.align.products import write_products

            write_products(campaign, manifest, sc, sa, s, previous, log)
        out.scenes.append(sa)
        extras[sc.id] = extra
        if store is not None:
            _write_labels(store, sa, label_kinds)
    if write:
        save_alignment(out, campaign)
    if report and write:
        from solidkit.align.report import write_report

        write_report(campaign, manifest, out)
    return out


def _write_labels(store: Any, sa: SceneAlignment, kinds: tuple[str, ...] | None = None) -> None:
    """Auto labels (C2): sun per capture, sun_scene, heading per capture, probe_pixel from geometry."""
    kinds = kinds or ("sun", "sun_scene", "heading", "probe_pixel")
    for cs in sa.sun.captures if "sun" in kinds else []:
        if cs.source != "auto":
            continue
        value: dict[str, Any] = {"found": cs.found, "azimuth_deg": cs.azimuth_deg, "elevation_deg": cs.elevation_deg,
                                 "uncertainty_deg": cs.uncertainty_deg,
                                 "candidates": [c.model_dump(include={"azimuth_deg", "elevation_deg", "size_deg", "chosen", "reasons"})
                                                for c in cs.candidates]}
        store.put("sun", f"{sa.id}/{cs.probe}", value, source="auto", annotator=ANNOTATOR, flags=_flag_names(cs.flags))
    sun = sa.sun
    if "sun_scene" in kinds:
        store.put("sun_scene", sa.id, {"found": sun.found and sun.azimuth_deg is not None,
                                       "azimuth_deg": sun.azimuth_deg if sun.found else None,
                                       "elevation_deg": sun.elevation_deg if sun.found and sun.azimuth_deg is not None else None,
                                       "uncertainty_deg": sun.uncertainty_deg},
                  source="auto", annotator=ANNOTATOR, flags=_flag_names(sun.flags))
    for pa in sa.probes:
        if "heading" in kinds and pa.yaw_deg is not None and pa.yaw_source == "auto":
            store.put("heading", f"{sa.id}/{pa.id}", {"yaw_deg": pa.yaw_deg, "residual_deg": pa.residual_deg},
                      source="auto", annotator=ANNOTATOR, flags=_flag_names(pa.flags))
        if "probe_pixel" in kinds and pa.pixel_source == "geometry" and pa.pixel_full is not None:
            store.put("probe_pixel", f"{sa.id}/{pa.id}", {"x": max(pa.pixel_full[0], -0.5), "y": max(pa.pixel_full[1], -0.5)},
                      source="auto", annotator=ANNOTATOR, flags=_flag_names(pa.flags))


def _flag_names(flags: list[str]) -> list[str]:
    """Store flags are names: the code of each flag (:class:`~solidkit.flags.Flag`), each once."""
    names = []
    for code in flag_codes(flags):
        n = re.sub(r"[^A-Za-z0-9_.-]", "_", code)[:64]
        if n and n not in names:
            names.append(n)
    return names
