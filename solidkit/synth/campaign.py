"""The virtual field campaign: what a field team following ``docs/field-protocol.md`` brings home, plus the truth.

``solidkit synth campaign --scenes 29 --probes 67 --out DIR --seed S`` writes::

    DIR/card/<scene>/photo/IMG_0001.JPG        the limited-FOV photo (EXIF: focal length, time, GPS, heading)
    DIR/card/<scene>/cam/R0010001.JPG ...      Theta shots at the photo camera's position
    DIR/card/<scene>/p01/R0010006.JPG ...      Theta shots at each probe position
    DIR/card/<scene>/fieldnotes.toml           the field notes (:mod:`solidkit.capture.fieldnotes`)
    DIR/truth/truth.json                       :class:`CampaignTruth` (kept apart from the card)
    DIR/truth/<scene>/photo.exr, <probe>.exr   HDR photo and HDR local probes (256x128, photo pano frame)

(the card follows the *explicit* layout of :mod:`solidkit.capture.grouping`, so ``solidkit
ingest DIR/card CAMPAIGN`` reads it). The protocol, rule by rule:

- **Probes a person can reach** (:mod:`solidkit.synth.fieldwork`): on the road, sidewalks,
  markings or bench seats (up-facing, <= ``max_surface_height_m`` high, <= ``max_probe_distance_m``
  from the photo camera), lens ``lens_height_m`` (10 cm) above the surface, nothing overhead,
  ``probe_clearance_m`` of free space around the lens; one per photo quadrant first.
- **The camera position**: the first Theta position stands where the photo camera stood
  (folder ``cam``; the notes' ``camera_position``).
- **Exposures**: every position gets one bracket: the sun frame (``low_exposure_s`` 1/25000 s,
  ISO 64), the paper's probe exposure (``normal_exposure_s`` 1/2500 s, ISO 100) and
  ``brackets_s`` (default 1/640, 1/160, 1/40 s), ``shot_interval_s`` (3 s) apart, so ingest's
  10-s bracket gap groups them into one HDR product and the shortest is the sun frame.
- **Timing**: positions follow the photo every ``position_interval_s`` (60 s).
- **Field notes** (``fieldnotes.toml``): camera position, photo name, each probe's pixel as
  marked by hand (the exact pixel + ``mark_noise_px`` rms noise, rounded to half pixels; the
  truth keeps both), the photo's pitch/roll off the tripod level (``level_noise_deg`` rms).
- **Photo EXIF**: FocalLength and FocalLengthIn35mmFilm (on the 43.27 mm diagonal, as
  ``solidkit calibrate camera`` reads it), time + UTC offset, GPS and GPSImgDirection.
- **Glass facades** (a case the protocol says to avoid, which alignment must survive): every
  ``glass_every``-th scene (scene02, scene05, ...) has curtain-wall glass along both sides of
  the street and a lighting whose sun glint at least one position sees
  (``CaptureTruth.glint_body``).

Lightings are redrawn (up to ``sun_attempts``) until the sun reaches the photo camera's position
(and, for a glass scene, a glint is visible), as a field team would pick a sunny spot; the truth
says for every capture whether the sun is visible from it. A Theta shot is a dual-fisheye JPEG
(Ricoh THETA V layout, EXIF + Ricoh maker note: image type 2, ``[roll, pitch]`` as its
accelerometer would record them, with ``gravity_noise_deg`` noise; compass heading with
``compass_noise_deg`` noise) made through the lens profile of :mod:`solidkit.camera.lens`
(``theta-v`` scaled to ``fisheye_width``) by the capture forward model
:func:`solidkit.capture.unwarp.render_fisheye` (``R_level`` = the body's true rotation
``R(heading, pitch, roll)``) from an HDR panorama rendered at the position (scene frame). Both
lenses share one centre (the ~2 cm baseline is ignored).

Radiometry: scene radiance ``L`` (relative units of :mod:`solidkit.synth.lighting`) becomes the
sensor value ``x = K_SENSOR L t (ISO/100) / N^2`` (``K_SENSOR = 3500``: radiance 1 at 1/2500 s,
f/2, ISO 100 gives 0.35), plus shot and read noise (``var = 1e-3 x + 2e-3^2``), clipped to [0, 1]
(the sun saturates even at 1/25000 s, as on a real Theta), through the sRGB response,
quantised to 8 bits and JPEG-compressed. Renders go through
:func:`solidkit.synth.sample.suppress_fireflies` first (the sun's own pixels protected): an
isolated caustic would otherwise saturate even the 1/25000 s frame and pass for the sun. The photo uses f/2.8, ISO
100 and an automatic exposure putting the mean at 0.18.

Truth probes (:mod:`solidkit.synth.truth_probes`): the HDR probe each capture position's aligned
probe is held against, rendered from the same scene, lighting and position as its Theta shots, with
``probe_spp`` samples per pixel (default 256, times ``glass_spp_factor`` in glass scenes), and more
(up to ``probe_max_spp``, 2048) where that first render's measured noise is under ``probe_noise_db``
(40 dB PSNR in the paper's tonemap), so that the truth's own Monte Carlo noise stays below the
aligned probes' errors; the render record (spp, passes, seed, measured noise, fireflies replaced,
recipe version) goes into :attr:`ProbeTruth.render` and the EXR header. Cost on one busy CPU
thread: 15-70 s per probe, 1-5 min in a glass scene (seed 11: 24 probes in 18 min;
``benchmarks/results/align-truth.md``). ``solidkit synth campaign-truth DIR`` (:mod:`solidkit.synth.truth_rerender`)
re-renders only the truth probes of an existing campaign, leaving its card untouched.

Frames (truth): the scene frame of :mod:`solidkit.synth.scene` (x east, y down, z north); a
Theta body frame is our camera frame with z = front lens; ``R_scene_from_body =
R(yaw, pitch, roll)``; ``R_pano_from_body = R_y(photo yaw)^T R_scene_from_body`` is what aligning
a capture to the photo's panorama frame must recover.

Time, GPS and heading are tied to the sun (:mod:`solidkit.synth.solar`): the scene frame is
x east, z north, so the photo camera's **true heading** (clockwise from true north) is its yaw,
written to the photo's EXIF ``GPSImgDirection`` (ref ``T``) and to the truth
(``SceneTruth.heading_deg``). For each scene :func:`solidkit.synth.solar.place_sun` picks a day,
a whole-second UTC time, a latitude, longitude and altitude at which pvlib's solar azimuth
(clockwise from north) and apparent elevation equal the rendered sun's (scene frame; equivalently
``solar azimuth = heading + sun azimuth in the photo's panorama frame``, which is positive to the
right of forward). The photo's EXIF carries the local clock time (nominal zone ``round(lon/15)``
h), ``OffsetTime(Original)`` and the UTC ``GPSDateStamp``/``GPSTimeStamp``. Overcast scenes get
a sun direction drawn for the place and time (elevation 15-60°), hidden by the clouds. Theta
shots follow the photo by ``position_interval_s`` per position, so the real sun would have moved by
``CaptureTruth.sun_drift_deg`` (≤ 0.25°/min) from the rendered one; the photo is exact.

Resuming: ``truth/campaign.json`` fixes the settings (seed, scenes, probes, config, Mitsuba
variant) when the folder is created; a re-run with other settings is refused, naming them.
``truth/<scene>/scene.json`` (that scene's :class:`SceneTruth`, written atomically last) marks
a complete scene: a re-run skips complete scenes (and logs it), and renders an incomplete one
again from scratch (its card and truth folders are cleared first). Every scene depends only on
``(seed, scene index)`` and the shot numbers of the scenes before it, so an interrupted and
resumed campaign writes the same truth as an uninterrupted one.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import math
import os
import shutil
from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np

from solidkit.calibration.camera import FULL_FRAME_DIAGONAL_MM
from solidkit.camera.lens import load_profile
from solidkit.capture.fieldnotes import NOTES_NAMES, FieldNotes, PhotoPose, ProbeNote, notes_text
from solidkit.capture.unwarp import render_fisheye
from solidkit.envmap import (
    CONVENTIONS_VERSION,
    angles_from_direction,
    angular_distance,
    rotation_from_ypr,
    srgb_encode,
    write_exr,
)
from solidkit.errors import InputError
from solidkit.fsutil import atomic_write_bytes, atomic_write_text
from solidkit.synth.cameras import equirect_sensor, pinhole_sensor
from solidkit.synth.campaign_truth import (
    PRESETS,
    SCHEMA_VERSION,
    CampaignConfig,
    CampaignTruth,
    CaptureTruth,
    PhotoTruth,
    ProbeTruth,
    SceneTruth,
    Shot,
    SolarTruth,
    load_truth,
)
from solidkit.synth.exif import exif_app1, insert_app1
from solidkit.synth.fieldwork import GlassPanel, add_glass_facades, glint_direction, occluded, pick_reachable_probes
from solidkit.synth.mitsuba_variant import mitsuba, variant
from solidkit.synth.sample import (
    Generator,
    SampleConfig,
    derive_seed,
    render_buffers,
    render_clean,
    sun_mask_image,
    sun_mask_panorama,
)
from solidkit.synth.scene import CATEGORIES, to_mitsuba
from solidkit.synth.solar import place_sun, solar_angles_deg, solar_direction, solar_position, utc_offset_text
from solidkit.synth.truth_probes import clean_truth_probe

__all__ = [
    "sample_config",
    "K_SENSOR",
    "PRESETS",
    "CampaignConfig",
    "Shot",
    "ProbeTruth",
    "CaptureTruth",
    "PhotoTruth",
    "SceneTruth",
    "SolarTruth",
    "CampaignTruth",
    "expose",
    "generate_campaign",
    "load_truth",
    "open_campaign",
    "scene_block",
    "scene_lighting",
    "write_truth_exr",
    "SCENE_FILE",
    "SETTINGS_FILE",
]

K_SENSOR = 3500.0
SETTINGS_FILE = "campaign.json"
SCENE_FILE = "scene.json"
log = logging.getLogger(__name__)


def expose(
    radiance: np.ndarray,
    exposure_time: float,
    f_number: float,
    iso: float,
    rng: np.random.Generator,
    *,
    quality: int = 92,
) -> tuple[np.ndarray, bytes]:
    """Sensor model of the module doc: HDR radiance ``(H, W, 3)`` -> 8-bit sRGB image and its JPEG bytes."""
    x = K_SENSOR * np.clip(radiance, 0.0, None) * exposure_time * (iso / 100.0) / f_number**2
    x = x + rng.standard_normal(x.shape) * np.sqrt(1e-3 * np.clip(x, 0.0, 1.0) + 2e-3**2)
    img = np.round(np.asarray(srgb_encode(np.clip(x, 0.0, 1.0))) * 255.0).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise InputError("JPEG encoding failed")
    return img, buf.tobytes()


def write_truth_exr(path: Path, image: np.ndarray, meta: dict[str, Any]) -> None:
    """Truth radiance ``(H, W, 3)`` to ``path`` as half floats when it fits (0.05 % steps, half the bytes), else
    float32."""
    half = bool(np.nanmax(np.abs(image)) < 0.5 * np.finfo(np.float16).max)
    write_exr(path, image, meta, half=half)


def _split(total: int, parts: int) -> list[int]:
    return [total // parts + (1 if i < total % parts else 0) for i in range(parts)]


def open_campaign(
    out: Path, scenes: int, probes: int, seed: int, config: CampaignConfig, variant: str
) -> dict[str, Any]:
    """Create ``truth/campaign.json`` or check that the existing one has the same settings.

    Raises :class:`InputError` naming every differing setting, or when ``out`` holds files but
    no campaign settings.
    """
    settings = {
        "kind": "solidkit-synth-campaign-settings",
        "schema_version": SCHEMA_VERSION,
        "conventions_version": CONVENTIONS_VERSION,
        "seed": int(seed),
        "scenes": int(scenes),
        "probes": int(probes),
        "variant": variant,
        "config": config.model_dump(mode="json"),
    }
    path = out / "truth" / SETTINGS_FILE
    if path.is_file():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError):
            raise InputError(f"{path}: unreadable campaign settings; use a new --out") from None
        flat_old, flat_new = _flatten(old), _flatten(settings)
        diff = [
            f"{k}: {flat_old.get(k, '-')} here, {flat_new.get(k, '-')} asked"
            for k in sorted(set(flat_old) | set(flat_new))
            if flat_old.get(k) != flat_new.get(k)
        ]
        if diff:
            raise InputError(
                f"{out}: holds a campaign made with other settings ({'; '.join(diff)}); "
                "re-run with the same settings to resume, or use a new --out"
            )
        return old
    if out.exists() and any((out / d).exists() for d in ("card", "truth")):
        raise InputError(f"{out}: holds card/ or truth/ but no {SETTINGS_FILE}; use a new --out")
    atomic_write_text(path, json.dumps(settings, indent=1))
    return settings


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _load_scene(path: Path) -> SceneTruth | None:
    """A complete scene's truth, or None (absent or unreadable: the scene is rendered again)."""
    if not path.is_file():
        return None
    try:
        return SceneTruth.model_validate_json(path.read_text())
    except (OSError, ValueError) as exc:
        log.warning("%s: unreadable (%s); rendering the scene again", path, str(exc).splitlines()[0])
        return None


def _last_shot_no(scene: SceneTruth) -> int:
    """Highest Theta file number ``R001xxxx`` used by a scene (0 if none)."""
    nos = [int(Path(sh.file).stem[1:]) - 10000 for c in scene.captures for sh in c.shots]
    return max(nos, default=0)


def sample_config(cfg: CampaignConfig) -> SampleConfig:
    """The scene generator's settings of a campaign's photos (:class:`~solidkit.synth.sample.SampleConfig`)."""
    return SampleConfig(
        width=cfg.photo_width,
        height=cfg.photo_height,
        hfov_deg=cfg.hfov_deg,
        candidates=cfg.candidates,
        p_sunsky=cfg.p_sunsky,
        probe_height=cfg.probe_height,
        block_length=cfg.block_length,
    )


def generate_campaign(
    out: str | os.PathLike,
    scenes: int,
    probes: int,
    *,
    seed: int = 0,
    config: CampaignConfig | None = None,
    progress: Any = None,
) -> CampaignTruth:
    """Render the campaign (see module doc) into ``out``; returns the truth (also written to truth/truth.json).

    Resumable and idempotent: complete scenes (``truth/<scene>/scene.json``) are skipped; other
    settings than those ``out`` was created with raise :class:`InputError`. ``progress(scene_id,
    capture_id)`` is called once per capture, skipped ones included.
    """
    if scenes < 1 or probes < 0:
        raise InputError("--scenes must be >= 1 and --probes >= 0")
    mi = mitsuba()
    cfg = config or CampaignConfig()
    out = Path(out)
    truth_dir = out / "truth"
    open_campaign(out, scenes, probes, seed, cfg, variant())
    profile = load_profile(cfg.lens_profile)
    rw, rh = profile.reference_size
    profile = profile.scaled(cfg.fisheye_width, int(round(cfg.fisheye_width * rh / rw)))
    scfg = sample_config(cfg)
    gen = Generator(seed, scfg)
    per_scene = _split(probes, scenes)
    shot_no = 1
    scenes_truth = []
    rendered = skipped = 0
    for s in range(scenes):
        sid = f"scene{s + 1:02d}"
        marker = truth_dir / sid / SCENE_FILE
        st = _load_scene(marker)
        if st is not None:
            skipped += 1
            log.info("%s: complete (%s), skipped", sid, marker.relative_to(out))
            if progress:
                for c in st.captures:
                    progress(sid, c.id)
        else:
            for d in (out / "card" / sid, truth_dir / sid):  # leftovers of an interrupted run
                if d.is_dir():
                    shutil.rmtree(d)
            st = _render_scene(out, s, sid, seed, cfg, gen, per_scene[s], shot_no, profile, mi, progress)
            text = st.model_dump_json(indent=1)
            atomic_write_text(marker, text)  # last: marks the scene complete
            st = SceneTruth.model_validate_json(text)  # as a resumed run would read it
            rendered += 1
        shot_no = max(shot_no, _last_shot_no(st) + 1)
        scenes_truth.append(st)
    if skipped:
        log.info("campaign %s: %d scene(s) rendered, %d complete scene(s) skipped", out, rendered, skipped)
    truth = CampaignTruth(
        seed=seed,
        scenes_requested=scenes,
        probes_requested=probes,
        config=cfg,
        renderer={"mitsuba": mi.__version__, "variant": variant()},
        radiometry={
            "K_SENSOR": K_SENSOR,
            "response": "sRGB (IEC 61966-2-1)",
            "noise": "var = 1e-3 x + (2e-3)^2, x in [0, 1] before clipping",
            "lens_profile": cfg.lens_profile,
            "fisheye_size": list(profile.reference_size),
        },
        scenes=scenes_truth,
    )
    atomic_write_text(truth_dir / "truth.json", truth.model_dump_json(indent=1))
    return truth


def scene_block(
    gen: Generator, s: int, sector: int, seed: int, cfg: CampaignConfig
) -> tuple[Any, Any, list[GlassPanel], bool]:
    """Scene ``s``'s city block (with its glass facades in a glass scene), photo camera, glass panels, glass flag
    (the same for the same arguments: :mod:`solidkit.synth.truth_rerender` rebuilds scenes with it)."""
    block, (cam, _) = gen.block_and_view(s, sector)
    glass = cfg.glass_every > 0 and s % cfg.glass_every == min(1, cfg.glass_every - 1)
    panels: list[GlassPanel] = []
    if glass:
        block, panels = add_glass_facades(block, np.random.default_rng(derive_seed(seed, s, 81)))
    return block, cam, panels, glass


def scene_lighting(
    mi: Any,
    gen: Generator,
    geometry: Any,
    cam: Any,
    positions: list[np.ndarray],
    panels: list[GlassPanel],
    glass: bool,
    s: int,
    seed: int,
    cfg: CampaignConfig,
    sid: str,
) -> Any:
    """A sunny spot (and, for a glass scene, a sun whose glint some position sees), as a team would pick; the
    lighting of scene ``s`` (``sid``) of :func:`scene_block`, ``positions`` its capture positions (scene frame)."""
    attempts = cfg.sun_attempts * (4 if glass else 1)  # a glint needs the sun on the glass and at a position
    for attempt in range(attempts):
        light = gen.lighting(derive_seed(seed, s, 300 + attempt))
        if light.sun is not None and solar_angles_deg(light.sun)[1] < -0.5:
            continue  # a sun below the horizon (an odd HDR map) has no place and time
        if glass and light.sun is None:
            continue
        if light.sun is not None and occluded(mi, geometry, cam.position, light.sun):
            continue
        if glass and not any(
            glint_direction(mi, geometry, pos, cast(np.ndarray, light.sun), panels) is not None for pos in positions
        ):
            continue
        break
    else:
        log.warning(
            "%s: no lighting in %d attempts met the protocol (sun at the camera%s); kept the last",
            sid,
            attempts,
            ", a visible glint" if glass else "",
        )
    return light


def probe_exr_meta(sid: str, cid: str, record: dict[str, Any]) -> dict[str, Any]:
    """The EXR header attributes of a truth probe (its render record among them)."""
    return {"scene": sid, "probe": cid, "frame": "photo panorama frame", **{f"truth_{k}": v for k, v in record.items()}}


def _render_scene(
    out: Path,
    s: int,
    sid: str,
    seed: int,
    cfg: CampaignConfig,
    gen: Generator,
    n_probes: int,
    shot_no: int,
    profile: Any,
    mi: Any,
    progress: Any,
) -> SceneTruth:
    """Render scene ``s`` (photo, probes, Theta captures, field notes) into ``out``; returns its truth (not yet
    written)."""
    truth_dir = out / "truth"
    model = profile.camera_models[0] if profile.camera_models else "RICOH THETA V"
    rng = np.random.default_rng(derive_seed(seed, s, 77))
    sector = int(rng.integers(6))
    block, cam, panels, glass = scene_block(gen, s, sector, seed, cfg)
    geometry = to_mitsuba(block, None, tex_size=4)
    # --- where the team can put the Theta: the photo camera's position, then probes on reachable surfaces
    buf = render_buffers(geometry, cam, spp=1, shadows=False)
    picks = pick_reachable_probes(
        mi,
        geometry,
        block,
        cam,
        buf,
        n_probes,
        rng,
        lens_height_m=cfg.lens_height_m,
        clearance_m=cfg.probe_clearance_m,
        max_surface_height_m=cfg.max_surface_height_m,
        max_distance_m=cfg.max_probe_distance_m,
    )
    if len(picks) < n_probes:
        log.warning("%s: only %d of %d probe positions are reachable in this view", sid, len(picks), n_probes)
    R = cam.rotation
    positions: list[tuple[str, np.ndarray, dict[str, Any] | None]] = [("cam", cam.position.copy(), None)]
    for k, p in enumerate(picks):
        x, y = p["pixel"]
        point = p["point"]
        spot = {
            "pixel": [int(x), int(y)],
            "quadrant": p["quadrant"],
            "point_scene": point.tolist(),
            "normal_scene": p["normal"].tolist(),
            "point_camera": ((point - cam.position) @ R).tolist(),
            "depth": float(buf["depth"][y, x]),
            "category": CATEGORIES[block.category_of(np.array([p["label"]]))[0]],
            "surface_height_m": float(-point[1]) + 0.0,
        }
        positions.append((f"p{k + 1:02d}", p["position"], spot))
    light = scene_lighting(mi, gen, geometry, cam, [pos for _, pos, _ in positions], panels, glass, s, seed, cfg, sid)
    scene = to_mitsuba(block, light.emitter())
    # place and time: pvlib's sun = the rendered sun (overcast: a daytime sun hidden by the clouds)
    srng = np.random.default_rng(derive_seed(seed, s, 79))
    sun_dir = (
        light.sun if light.sun is not None else solar_direction(srng.uniform(0.0, 360.0), srng.uniform(15.0, 60.0))
    )
    fix = place_sun(sun_dir, srng)
    heading = math.degrees(cam.yaw) % 360.0
    t0 = fix.when_local
    gps = (fix.lat_deg, fix.lon_deg, fix.alt_m)
    # --- the photo
    # glass reflects the sun onto the street (caustics): more samples keep that noise near the others' level
    spp_scale = cfg.glass_spp_factor if glass else 1
    photo_spp = cfg.photo_spp * spp_scale
    hdr, _ = render_clean(
        scene,
        pinhole_sensor(cam, spp=photo_spp, seed=derive_seed(seed, s, 1)),
        photo_spp,
        seed=derive_seed(seed, s, 1),
        protect=sun_mask_image(light.sun, cam, 6.0),
        firefly_k=cfg.firefly_k,
        denoise=cfg.denoise,
    )
    f_number, iso = 2.8, 100
    mean = float(np.mean(hdr))
    t_photo = 0.18 * f_number**2 / (K_SENSOR * max(mean, 1e-9) * iso / 100.0)
    _, jpg = expose(hdr, t_photo, f_number, iso, rng, quality=cfg.jpeg_quality)
    sensor_w = 6.17
    f_mm = cam.K[0, 0] * sensor_w / cam.width
    # FocalLengthIn35mmFilm is defined on the 43.27 mm diagonal (CIPA DC-008), as calibrate camera reads it
    f_35 = cam.K[0, 0] * FULL_FRAME_DIAGONAL_MM / math.hypot(cam.width, cam.height)
    app = exif_app1(
        make="SOLIDKIT",
        model="Virtual Photo Camera",
        when=t0,
        exposure_time=t_photo,
        f_number=f_number,
        iso=iso,
        gps=gps,
        focal_length_mm=f_mm,
        focal_35mm=f_35,
        img_direction_deg=heading,
    )
    photo_name = f"IMG_{s + 1:04d}.JPG"
    photo_file = f"card/{sid}/photo/{photo_name}"
    atomic_write_bytes(out / photo_file, insert_app1(jpg, app))
    write_truth_exr(truth_dir / sid / "photo.exr", hdr, {"scene": sid})
    photo = PhotoTruth(
        shot=Shot(file=photo_file, exposure_time=t_photo, f_number=f_number, iso=iso, time=t0, role="photo"),
        camera=cam.to_json(),
        focal_length_mm=f_mm,
        sensor_width_mm=sensor_w,
        focal_35mm=f_35,
        hdr_file=f"truth/{sid}/photo.exr",
    )
    # --- the Theta positions: the camera's first, then the probes, one every position_interval_s
    captures = []
    for c, (cid, pos, info) in enumerate(positions):
        tc = t0 + dt.timedelta(seconds=cfg.position_interval_s * (c + 1))
        yaw = rng.uniform(-math.pi, math.pi)
        tilt = math.radians(cfg.max_tilt_deg)
        pitch, roll = rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt)
        Rb = np.asarray(rotation_from_ypr(yaw, pitch, roll))
        rec_pitch = math.degrees(pitch) + rng.normal(0.0, cfg.gravity_noise_deg)
        rec_roll = math.degrees(roll) + rng.normal(0.0, cfg.gravity_noise_deg)
        rec_heading = (math.degrees(yaw) + rng.normal(0.0, cfg.compass_noise_deg)) % 360.0
        keep = sun_mask_panorama(light.sun, np.eye(3), cfg.pano_height, 2.0)
        glint = glint_direction(mi, geometry, pos, light.sun, panels) if (panels and light.sun is not None) else None
        if glint is not None:  # a glint is a real, sharp highlight: not a firefly
            assert keep is not None  # a glint needs a sun
            keep = keep | cast(np.ndarray, sun_mask_panorama(glint, np.eye(3), cfg.pano_height, 2.0))
        pano_spp = cfg.pano_spp * spp_scale
        pseed = derive_seed(seed, s, 100 + c)
        pano, _ = render_clean(
            scene,
            equirect_sensor(pos, np.eye(3), cfg.pano_height, jitter=True, spp=pano_spp, seed=pseed),
            pano_spp,
            seed=pseed,
            protect=keep,
            firefly_k=cfg.firefly_k,
            wrap=True,
            denoise=cfg.denoise,
        )
        fish = render_fisheye(pano, profile, profile.reference_size, R_level=Rb)
        shots = []
        plan = [(cfg.low_exposure_s, 64, "low_exposure"), (cfg.normal_exposure_s, 100, "normal")]
        plan += [(t_b, 100, "bracket") for t_b in cfg.brackets_s]
        for k, (t_exp, iso_c, role) in enumerate(plan):
            when = tc + dt.timedelta(seconds=cfg.shot_interval_s * k)
            _, jpg = expose(fish, t_exp, 2.0, iso_c, rng, quality=cfg.jpeg_quality)
            app = exif_app1(
                make="RICOH",
                model=model,
                when=when,
                exposure_time=t_exp,
                f_number=2.0,
                iso=iso_c,
                gps=gps,
                theta={"image_type": 2, "roll_deg": rec_roll, "pitch_deg": rec_pitch, "heading_deg": rec_heading},
            )
            f = f"card/{sid}/{cid}/R{10000 + shot_no:07d}.JPG"
            shot_no += 1
            atomic_write_bytes(out / f, insert_app1(jpg, app))
            shots.append(Shot(file=f, exposure_time=t_exp, f_number=2.0, iso=iso_c, time=when, role=role))
        probe = None
        if info is not None:
            base = cfg.probe_spp * spp_scale
            local, record = clean_truth_probe(
                scene,
                pos,
                cam.pano_rotation,
                cfg.probe_height,
                base,
                seed=derive_seed(seed, s, 200 + c),
                noise_target_db=cfg.probe_noise_db,
                max_spp=max(base, cfg.probe_max_spp),
                sun=light.sun,
                glint=glint,
                firefly_k=cfg.firefly_k,
                firefly_spp=cfg.pano_spp * spp_scale,
            )
            assert local is not None  # rendered: no pilot given
            write_truth_exr(truth_dir / sid / f"{cid}.exr", local, probe_exr_meta(sid, cid, record))
            marked = np.asarray(info["pixel"], np.float64) + rng.normal(0.0, cfg.mark_noise_px, 2)
            marked = (
                np.round(np.clip(marked, 0.0, [cam.width - 1, cam.height - 1]) * 2.0) / 2.0
            )  # a tablet's half pixels
            probe = ProbeTruth(**info, marked_pixel=marked.tolist(), hdr_file=f"truth/{sid}/{cid}.exr", render=record)
        sun_body = sun_drift = None
        if light.sun is not None:
            sun_body = (Rb.T @ light.sun).tolist()
            normal_time = next(sh.time for sh in shots if sh.role == "normal")
            real = solar_direction(*solar_position(normal_time, fix.lat_deg, fix.lon_deg, fix.alt_m))
            sun_drift = math.degrees(float(angular_distance(real, light.sun)))
        sun_visible = light.sun is not None and not occluded(mi, geometry, pos, light.sun)
        captures.append(
            CaptureTruth(
                id=cid,
                kind="probe" if info is not None else "camera_position",
                position=pos.tolist(),
                yaw_deg=math.degrees(yaw),
                pitch_deg=math.degrees(pitch),
                roll_deg=math.degrees(roll),
                R_scene_from_body=Rb.tolist(),
                R_pano_from_body=(cam.pano_rotation.T @ Rb).tolist(),
                recorded_pitch_deg=rec_pitch,
                recorded_roll_deg=rec_roll,
                recorded_heading_deg=rec_heading,
                sun_body=sun_body,
                sun_visible=sun_visible,
                sun_drift_deg=sun_drift,
                glint_body=None if glint is None else (Rb.T @ glint).tolist(),
                shots=shots,
                probe=probe,
            )
        )
        if progress:
            progress(sid, cid)
    sun_az = sun_el = None
    if light.sun is not None:
        az, el = angles_from_direction(cam.pano_rotation.T @ light.sun)
        sun_az, sun_el = math.degrees(float(az)), math.degrees(float(el))
    solar = SolarTruth(
        time_utc=fix.when_utc,
        utc_offset=utc_offset_text(fix.utc_offset_min),
        latitude_deg=fix.lat_deg,
        longitude_deg=fix.lon_deg,
        altitude_m=fix.alt_m,
        azimuth_deg=fix.azimuth_deg,
        elevation_deg=fix.elevation_deg,
        error_deg=fix.error_deg,
        rendered=light.sun is not None,
    )
    # --- the field notes, as the team fills them in at the scene (pixels as marked, pose off a level)
    pose = PhotoPose(
        pitch_deg=round(math.degrees(cam.pitch) + float(rng.normal(0.0, cfg.level_noise_deg)), 1),
        roll_deg=round(math.degrees(cam.roll) + float(rng.normal(0.0, cfg.level_noise_deg)), 1),
    )
    notes = FieldNotes(
        camera_position="cam",
        photo=photo_name,
        photo_pose=pose,
        notes=f"{light.meta.get('kind', 'lighting')}; "
        + ("curtain-wall glass along the street" if glass else "no glass facades"),
        probes={
            c.id: ProbeNote(pixel=tuple(c.probe.marked_pixel), note=f"on the {c.probe.category}")
            for c in captures
            if c.probe is not None
        },
    )
    notes_file = f"card/{sid}/{NOTES_NAMES[0]}"
    atomic_write_text(out / notes_file, notes_text(notes))
    return SceneTruth(
        id=sid,
        block_seed=block.seed,
        sector=sector,
        lighting=light.meta,
        sun_found=light.sun is not None,
        sun_scene=None if light.sun is None else [float(v) for v in light.sun],
        sun_azimuth_deg=sun_az,
        sun_elevation_deg=sun_el,
        heading_deg=heading,
        solar=solar,
        gps=list(gps),
        photo=photo,
        captures=captures,
        camera_position="cam",
        fieldnotes_file=notes_file,
        glass_panels=[p.to_json() for p in panels],
    )
