"""The alignment document ``CAMPAIGN/align/alignment.json`` (contract C3) and its frames.

Frames (docs/conventions.md §2, §4 and "Heading and alignment")
------------------------------------------------------------------
- **Body frame** of a Theta capture: our camera axes (x right, y down, z = the front lens).
- **Level frame** ``L_c`` of capture ``c``: the body frame levelled by gravity, keeping the
  Theta's own yaw: ``d_L = R_level d_body`` with ``R_level = R(0, pitch_c, roll_c)`` (recorded
  gravity, or the refined levelling of :class:`Levelling`). The ingest products ``sun_frame`` and
  ``hdr`` are panoramas in this frame (azimuth 0 = the front lens's horizontal direction).
- **Photo panorama frame** ``P`` of a scene: the conventions' panorama frame of the scene's photo
  (gravity-aligned, forward = the photo's optical axis projected onto the horizontal plane).
  The photo camera's orientation in ``P`` is ``R(0, photo_pitch, photo_roll)``.
- **World**: solar azimuth clockwise from true north, elevation above the horizon (pvlib).

Heading convention (the ``heading`` label of contract C2 and ``ProbeAlignment.yaw_deg``)
-------------------------------------------------------------------------------------------
Both ``L_c`` and ``P`` are level, so they differ by a rotation about gravity only::

    d_P = R_y(yaw_c) d_L                      (level frame of capture c -> photo panorama frame)
    d_P = R_y(yaw_c) R(0, pitch_c, roll_c) d_body = ProbeAlignment.rotation @ d_body

``yaw_c`` (degrees, wrapped to ``[-180, 180)``) is positive when the capture's front lens points
to the right of the photo's forward direction: a feature at azimuth ``a`` in the capture's level
panorama is at azimuth ``a + yaw_c`` in the photo's panorama. The photo's own pitch and roll do
not enter this rotation (they relate the photo *camera* to ``P``); they are recorded beside it.
An aligned probe panorama is ``rotate(level_panorama, R_y(yaw_c))`` (conventions §4).

With the compass: ``yaw_c = heading_c - photo_heading`` (both clockwise from north), and the
sun's world azimuth is ``A = photo_heading + azimuth_in_P = heading_c + azimuth_in_L_c``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from solidkit.document import read_json_object, validate_versioned
from solidkit.envmap.coords import CONVENTIONS_VERSION, rotation_from_ypr, rotation_y, wrap_angle
from solidkit.errors import InputError
from solidkit.fsutil import atomic_write_text

__all__ = [
    "SCHEMA_VERSION",
    "ALIGNMENT_FILE",
    "LabelSource",
    "SunCandidate",
    "Ephemeris",
    "CaptureSun",
    "SceneSun",
    "Levelling",
    "Cue",
    "ProbeProducts",
    "ProbeAlignment",
    "PhotoInfo",
    "SceneAlignment",
    "CampaignAlignment",
    "wrap_deg",
    "photo_azimuth_from_solar",
    "solar_azimuth_from_photo",
    "level_to_pano",
    "body_to_pano",
    "load_alignment",
    "save_alignment",
    "alignment_summary",
]

SCHEMA_VERSION = 1
ALIGNMENT_FILE = Path("align") / "alignment.json"
LabelSource = Literal["auto", "annotator", "reviewed"]
Matrix3 = list[list[float]]


def wrap_deg(angle: float) -> float:
    """``angle`` (degrees) wrapped to ``[-180, 180)`` (:func:`solidkit.envmap.coords.wrap_angle`)."""
    return float(wrap_angle(float(angle), 360.0))


def photo_azimuth_from_solar(solar_azimuth_deg: float, photo_heading_deg: float) -> float:
    """Azimuth in the photo's panorama frame of a direction with solar azimuth ``solar_azimuth_deg``
    (clockwise from true north), the photo's compass heading being ``photo_heading_deg``:
    ``solar_azimuth - photo_heading`` wrapped to ``[-180, 180)`` (conventions §7); degrees.

    >>> photo_azimuth_from_solar(10.0, 350.0), solar_azimuth_from_photo(20.0, 350.0)
    (20.0, 10.0)
    """
    return wrap_deg(solar_azimuth_deg - photo_heading_deg)


def solar_azimuth_from_photo(azimuth_deg: float, photo_heading_deg: float) -> float:
    """The inverse of :func:`photo_azimuth_from_solar`: ``photo_heading + azimuth`` in ``[0, 360)``; degrees."""
    return (azimuth_deg + photo_heading_deg) % 360.0


def level_to_pano(yaw_deg: float) -> np.ndarray:
    """``R_y(yaw)``: a capture's level frame -> the photo's panorama frame, ``(3, 3)`` float64."""
    return np.asarray(rotation_y(math.radians(yaw_deg)), dtype=np.float64)


def body_to_pano(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """``R_y(yaw) R(0, pitch, roll) = R(yaw, pitch, roll)``: a capture's body -> the photo's panorama frame.

    ``pitch_deg``, ``roll_deg``: the capture's levelling (conventions §4, §7); degrees.
    """
    return np.asarray(rotation_from_ypr(*(math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))), dtype=np.float64)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


# --------------------------------------------------------------------------- sun
class SunCandidate(_Model):
    """One saturated blob of a sun frame, in that capture's level frame."""

    azimuth_deg: float
    elevation_deg: float
    size_deg: float = Field(description="equivalent angular diameter of the saturated core, degrees")
    n_pixels: int
    contrast: float = Field(description="peak over the bright-sky level around it")
    chosen: bool = False
    reasons: list[str] = Field(default_factory=list, description="why it was rejected (empty for the chosen one)")
    scores: dict[str, float] = Field(default_factory=dict, description="per-test values, e.g. ephemeris_elevation_deg")


class Ephemeris(_Model):
    """pvlib's sun for a time and place (NREL SPA, apparent elevation)."""

    time_utc: str = Field(description="ISO 8601, UTC")
    latitude_deg: float
    longitude_deg: float
    altitude_m: float | None = None
    azimuth_deg: float = Field(description="clockwise from true north")
    elevation_deg: float = Field(description="apparent (refracted) elevation")
    time_source: str = Field("", description="which EXIF fields gave the time (and its UTC offset)")


class CaptureSun(_Model):
    """The sun seen by one capture: direction in its level frame (its sun_frame panorama)."""

    probe: str
    found: bool
    azimuth_deg: float | None = Field(None, description="level frame of the capture")
    elevation_deg: float | None = None
    uncertainty_deg: float | None = None
    reason: str = ""
    candidates: list[SunCandidate] = Field(default_factory=list)
    ephemeris: Ephemeris | None = Field(None, description="at this capture's own time")
    world_azimuth_deg: float | None = Field(
        None, description="azimuth from true north, once the capture's yaw is known"
    )
    source: LabelSource = "auto"
    flags: list[str] = Field(default_factory=list)


class SceneSun(_Model):
    """A scene's consensus sun: in the world and in the photo's panorama frame (at the photo's time)."""

    found: bool
    world_azimuth_deg: float | None = Field(None, description="clockwise from true north")
    world_elevation_deg: float | None = None
    azimuth_deg: float | None = Field(None, description="photo panorama frame")
    elevation_deg: float | None = None
    uncertainty_deg: float | None = None
    n_captures: int = Field(0, description="captures that saw the sun and entered the consensus")
    ephemeris: Ephemeris | None = Field(None, description="at the photo's time and place")
    motion: str = Field("", description="how the sun's motion between the captures' times was treated, and why")
    source: LabelSource = "auto"
    flags: list[str] = Field(default_factory=list)
    captures: list[CaptureSun] = Field(default_factory=list)


# --------------------------------------------------------------------------- probes
class Levelling(_Model):
    """How a capture was levelled: ``R_level = R(0, pitch, roll)`` (body -> level frame).

    ``source``: ``'metadata'`` (recorded gravity), ``'metadata+tilt'`` (the recorded gravity
    corrected by the residual tilt of the vertical edges, :func:`solidkit.envmap.tilt.residual_tilt`,
    weighted by both uncertainties) or ``'none'``. The ingest products are levelled with the
    metadata (``metadata_pitch_deg``/``metadata_roll_deg``); directions in them (sun labels) are
    in that frame.
    """

    pitch_deg: float
    roll_deg: float
    source: str = Field(description="'metadata' (recorded gravity), 'metadata+tilt' (refined), or 'none'")
    metadata_pitch_deg: float | None = None
    metadata_roll_deg: float | None = None
    residual_tilt_deg: float | None = Field(None, description="tilt of the metadata-levelled panorama's vertical edges")
    tilt_uncertainty_deg: float | None = Field(None, description="1-sigma of residual_tilt_deg")
    tilt_reliable: bool | None = None
    confidence: float | None = None


class Cue(_Model):
    """One independent estimate of a capture's yaw (degrees, heading convention above)."""

    yaw_deg: float | None
    sigma_deg: float | None = Field(None, description="1-sigma uncertainty of this cue")
    weight: float = 0.0
    ok: bool = Field(description="usable and consistent with the consensus")
    residual_deg: float | None = Field(None, description="cue minus consensus, wrapped")
    detail: str = ""


class ProbeProducts(_Model):
    """Aligned products (photo panorama frame), paths relative to the campaign."""

    ldr_full: str | None = None
    ldr_256: str | None = None
    hdr_256: str | None = None
    hdr_full: str | None = None
    saturation_256: str | None = None
    saturation_full: str | None = None


class ProbeAlignment(_Model):
    """One Theta capture of a scene rotated into the photo's panorama frame."""

    id: str
    role: Literal["camera", "probe"]
    pixel_full: list[float] | None = Field(None, description="[x, y] in full-resolution photo pixels")
    pixel_source: Literal["field_notes", "label", "geometry"] | None = None
    pixel_geometry: list[float] | None = Field(None, description="[x, y] predicted from the relative pose (check)")
    pixel_error_px: float | None = Field(None, description="distance between pixel_full and pixel_geometry")
    pixel_geometry_sigma_deg: float | None = Field(
        None, description="1-sigma angle of pixel_geometry's direction (from the baseline's fit)"
    )
    pixel_error_deg: float | None = Field(None, description="angle between the rays of pixel_full and pixel_geometry")
    levelling: Levelling
    rotation: Matrix3 = Field(description="3x3, capture body -> photo panorama frame: R_y(yaw) R(0, pitch, roll)")
    yaw_deg: float | None = Field(description="level frame -> photo panorama frame (heading convention); None: unknown")
    yaw_source: LabelSource = "auto"
    residual_deg: float | None = Field(None, description="weighted RMS of the agreeing cues about the consensus")
    yaw_sigma_deg: float | None = Field(None, description="1-sigma uncertainty of yaw_deg from the agreeing cues")
    cues: dict[str, Cue] = Field(default_factory=dict)
    flags: list[str] = Field(default_factory=list)
    products: ProbeProducts = Field(default_factory=ProbeProducts)


class PhotoInfo(_Model):
    """The scene's photo: original file, size, intrinsics, orientation."""

    path: str = Field(description="original, relative to the campaign")
    sha256: str
    size: list[int] = Field(description="[width, height], pixels")
    K_full: Matrix3
    K_source: str = ""
    pitch_deg: float | None = None
    roll_deg: float | None = None
    heading_deg: float | None = Field(None, description="compass, clockwise from true north (EXIF GPSImgDirection)")
    pitch_roll_source: str = Field(
        "", description="'exif', 'features' (estimated from the camera-position capture) or 'assumed_zero'"
    )
    time: str | None = Field(None, description="ISO 8601 with its UTC offset when known")


class SceneAlignment(_Model):
    """Everything align/ determined for one scene."""

    id: str
    photo: PhotoInfo | None
    camera_probe: str | None
    sun: SceneSun
    probes: list[ProbeAlignment] = Field(default_factory=list)
    flags: list[str] = Field(default_factory=list)

    def probe(self, pid: str) -> ProbeAlignment:
        for p in self.probes:
            if p.id == pid:
                return p
        raise KeyError(pid)


class CampaignAlignment(_Model):
    """``CAMPAIGN/align/alignment.json``."""

    kind: Literal["solidkit-alignment"] = "solidkit-alignment"
    schema_version: int = SCHEMA_VERSION
    conventions_version: int = CONVENTIONS_VERSION
    solidkit_version: str = ""
    manifest_sha256: str = Field("", description="of the manifest.json this was computed from")
    settings: dict = Field(default_factory=dict)
    scenes: list[SceneAlignment] = Field(default_factory=list)

    def scene(self, sid: str) -> SceneAlignment:
        for s in self.scenes:
            if s.id == sid:
                return s
        raise KeyError(sid)


def load_alignment(path: str | os.PathLike) -> CampaignAlignment:
    """Read ``alignment.json`` (or a campaign directory holding one); one-line errors."""
    p = Path(path)
    if p.is_dir():
        p = p / ALIGNMENT_FILE
    if not p.is_file():
        raise InputError(f"{p}: no alignment file (run `solidkit align CAMPAIGN` first)")
    data = read_json_object(p, InputError, "alignment")
    return validate_versioned(
        p,
        data,
        CampaignAlignment,
        kind_key="kind",
        kind="solidkit-alignment",
        version_key="schema_version",
        version=SCHEMA_VERSION,
        what="alignment file",
    )


def save_alignment(alignment: CampaignAlignment, campaign_dir: str | os.PathLike) -> Path:
    """Write ``CAMPAIGN/align/alignment.json`` atomically; returns its path."""
    p = Path(campaign_dir) / ALIGNMENT_FILE
    atomic_write_text(p, alignment.model_dump_json(indent=1) + "\n")
    return p


def alignment_summary(alignment: CampaignAlignment) -> dict[str, Any]:
    """The alignment in short, as ``solidkit align --json`` prints it: per scene its flags, its sun
    (photo panorama frame and from true north, degrees; per capture the sun found and how many
    candidates were rejected) and per probe its yaw (degrees), the source of that yaw, the residual,
    the cues that agree, the probe pixel (full-size photo, pixels) and its flags."""
    scenes = []
    for sa in alignment.scenes:
        scenes.append(
            {
                "scene": sa.id,
                "flags": sa.flags + sa.sun.flags,
                "sun": {
                    "found": sa.sun.found,
                    "azimuth_deg": sa.sun.azimuth_deg,
                    "elevation_deg": sa.sun.elevation_deg,
                    "world_azimuth_deg": sa.sun.world_azimuth_deg,
                    "uncertainty_deg": sa.sun.uncertainty_deg,
                    "captures": {
                        c.probe: {
                            "found": c.found,
                            "azimuth_deg": c.azimuth_deg,
                            "elevation_deg": c.elevation_deg,
                            "rejected": sum(1 for k in c.candidates if not k.chosen),
                        }
                        for c in sa.sun.captures
                    },
                },
                "probes": [
                    {
                        "id": p.id,
                        "role": p.role,
                        "yaw_deg": p.yaw_deg,
                        "yaw_source": p.yaw_source,
                        "residual_deg": p.residual_deg,
                        "cues_ok": sorted(k for k, c in p.cues.items() if c.ok),
                        "pixel_full": p.pixel_full,
                        "pixel_source": p.pixel_source,
                        "flags": p.flags,
                    }
                    for p in sa.probes
                ],
            }
        )
    return {"alignment": ALIGNMENT_FILE.as_posix(), "scenes": scenes}
