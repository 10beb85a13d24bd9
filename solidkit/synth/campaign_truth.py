"""The virtual campaign's settings and truth: pydantic schemas, presets and the truth reader.

Apart from the renderer (:mod:`solidkit.synth.campaign`) so that tests, measurements and the
labeling/test-set tools read a campaign's truth without Mitsuba. Frames and units are those of
:mod:`solidkit.synth.campaign` (scene frame x east, y down, z north; degrees; seconds).
The truth is kept apart from the card and read only by tests and measurements.
"""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import BaseModel, Field, SerializerFunctionWrapHandler, model_serializer

from solidkit.document import DocumentError, VersionedDocument, read_json_object
from solidkit.envmap import CONVENTIONS_VERSION
from solidkit.errors import ConventionsError
from solidkit.synth.solar import TEMPERATURE_C

__all__ = [
    "SCHEMA_VERSION",
    "FORMAT_VERSION",
    "TruthError",
    "PRESETS",
    "CampaignConfig",
    "Shot",
    "ProbeTruth",
    "CaptureTruth",
    "PhotoTruth",
    "SolarTruth",
    "SceneTruth",
    "CampaignTruth",
    "load_truth",
]

SCHEMA_VERSION = 3  # of the campaign settings file (truth/campaign.json); truth files before format 4
FORMAT_VERSION = 4  # of truth files (CampaignTruth)
_LEGACY_KIND = "solidkit-synth-campaign-truth"
_LEGACY_VERSIONS = (3,)  # schema 2 (camp_v0) lacks ProbeTruth.marked_pixel: never read by this schema


class CampaignConfig(BaseModel):
    """Settings of a campaign (recorded in the truth)."""

    photo_width: int = 640
    photo_height: int = 480
    hfov_deg: float = 60.0
    photo_spp: int = 32
    pano_height: int = 512
    pano_spp: int = 16
    probe_height: int = 128
    probe_spp: int = Field(
        256,
        description="samples per pixel of a truth probe's first render (solidkit.synth."
        "truth_probes); truth recipe 1: 32 (16 in its first campaigns), all",
    )
    probe_noise_db: float = Field(
        40.0,
        description="noise target of the truth probes (PSNR, paper tonemap): more "
        "samples where the first render is noisier; 0: none",
    )
    probe_max_spp: int = Field(2048, description="most samples per pixel a truth probe gets for its noise target")
    fisheye_width: int = 1920
    lens_profile: str = "theta-v"
    normal_exposure_s: float = 1 / 2500
    low_exposure_s: float = 1 / 25000
    brackets_s: list[float] = Field(
        default_factory=lambda: [1 / 640, 1 / 160, 1 / 40],
        description="longer exposures after the normal one, same bracket",
    )
    shot_interval_s: float = Field(3.0, description="between the shots of one position (one bracket: < 10 s)")
    position_interval_s: float = Field(
        60.0, description="from one Theta position to the next (the sun moves 0.25°/min)"
    )
    max_tilt_deg: float = 5.0
    gravity_noise_deg: float = 0.3
    compass_noise_deg: float = 5.0
    lens_height_m: float = Field(0.10, description="Theta lens above the probe's surface")
    max_surface_height_m: float = Field(1.0, description="highest surface a probe is put on (ground, curbs, benches)")
    probe_clearance_m: float = Field(0.30, description="free space around the lens at its height")
    max_probe_distance_m: float = Field(25.0, description="farthest probe from the photo camera (horizontal)")
    mark_noise_px: float = Field(2.0, description="rms error of the probe pixels the team marks in the field notes")
    level_noise_deg: float = Field(0.5, description="rms error of the photo pitch/roll read off the tripod level")
    glass_every: int = Field(
        3,
        description="every n-th scene (scene02, scene05, ...) has curtain-wall glass along "
        "the street and a sun whose glint a position sees; 0: none",
    )
    glass_spp_factor: int = Field(4, description="samples per pixel multiplier of glass scenes (sun caustics)")
    jpeg_quality: int = 92
    candidates: int = 8
    p_sunsky: float = 0.7
    block_length: float = 60.0
    sun_attempts: int = 8
    firefly_k: float = 10.0
    denoise: bool = Field(
        False,
        description="photo and Theta panoramas denoised by Open Image Denoise (albedo and normal guides); "
        "the truth probes never are",
    )

    @model_serializer(mode="wrap")
    def _plain_as_before(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        d: dict[str, Any] = handler(self)
        if not self.denoise:  # recorded only when on, so campaigns rendered without it stay as they were
            d.pop("denoise", None)
        return d


PRESETS: dict[str, dict[str, Any]] = {
    "default": {},
    # the campaign shipped in solidkit/assets/campaign_mini (a few MB): a small photo, one bracket exposure, JPEG
    # quality 85; panoramas, fisheyes and truth probes at the defaults (what its card and truth.json record)
    "mini": {"photo_width": 320, "photo_height": 240, "brackets_s": [1 / 250], "jpeg_quality": 85},
    # the mini preset with glass facades in every scene (sun glints; benchmarks/results/align-glass-*)
    "glass-mini": {
        "photo_width": 320,
        "photo_height": 240,
        "brackets_s": [1 / 250],
        "jpeg_quality": 85,
        "glass_every": 1,
    },
}


class Shot(BaseModel):
    file: str
    exposure_time: float
    f_number: float
    iso: int
    time: dt.datetime = Field(description="aware local civil time (the EXIF clock time with its UTC offset)")
    role: Literal["photo", "normal", "low_exposure", "bracket"]


class ProbeTruth(BaseModel):
    pixel: list[int] = Field(description="exact photo pixel of the probe's surface point")
    marked_pixel: list[float] = Field(description="the pixel the field notes give (marked by hand: a few px off)")
    surface_height_m: float = Field(description="the surface point's height above the ground")
    quadrant: int
    point_scene: list[float]
    normal_scene: list[float]
    point_camera: list[float]
    depth: float
    category: str
    hdr_file: str
    render: dict[str, Any] | None = Field(
        None,
        description="how the truth probe was rendered (solidkit.synth.truth_probes: "
        "spp, passes, seed, fireflies replaced, version); None: "
        "version 1, config.probe_spp in one pass",
    )


class CaptureTruth(BaseModel):
    id: str
    kind: Literal["camera_position", "probe"]
    position: list[float]
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    R_scene_from_body: list[list[float]]
    R_pano_from_body: list[list[float]]
    recorded_pitch_deg: float
    recorded_roll_deg: float
    recorded_heading_deg: float
    sun_body: list[float] | None
    sun_visible: bool = Field(description="the sun's centre is unoccluded from the capture position")
    sun_drift_deg: float | None = Field(
        None, description="angle between the rendered sun and pvlib's sun at the time of the capture's normal shot"
    )
    glint_body: list[float] | None = Field(
        None, description="body-frame direction of a sun glint on glass seen from the capture (None: none)"
    )
    shots: list[Shot]
    probe: ProbeTruth | None = None


class PhotoTruth(BaseModel):
    shot: Shot
    camera: dict[str, Any]
    focal_length_mm: float
    sensor_width_mm: float
    focal_35mm: float | None = Field(
        None, description="35 mm-equivalent focal length (diagonal), before EXIF rounds it"
    )
    hdr_file: str


class SolarTruth(BaseModel):
    """Where and when the photo was taken, and pvlib's sun there and then (module doc)."""

    time_utc: dt.datetime
    utc_offset: str = Field(description="local civil offset, as in EXIF OffsetTimeOriginal")
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    azimuth_deg: float = Field(description="pvlib solar azimuth, clockwise from true north")
    elevation_deg: float = Field(description="pvlib apparent (refracted) solar elevation")
    error_deg: float = Field(description="angle between pvlib's sun and the scene's sun direction")
    temperature_c: float = TEMPERATURE_C
    model: str = "pvlib.solarposition.get_solarposition (NREL SPA), apparent elevation, pressure from altitude"
    rendered: bool = Field(description="false for overcast lightings: the sun is there but hidden")


class SceneTruth(BaseModel):
    id: str
    block_seed: int
    sector: int
    lighting: dict[str, Any]
    sun_found: bool
    sun_scene: list[float] | None = Field(description="scene frame: x east, y down, z north")
    sun_azimuth_deg: float | None = Field(None, description="in the photo's panorama frame")
    sun_elevation_deg: float | None = None
    heading_deg: float = Field(
        description="true heading of the photo camera (its panorama frame's forward), "
        "clockwise from true north; EXIF GPSImgDirection"
    )
    solar: SolarTruth
    gps: list[float]
    photo: PhotoTruth
    captures: list[CaptureTruth]
    camera_position: str = Field("cam", description="the capture taken at the photo camera's position")
    fieldnotes_file: str | None = Field(None, description="the field notes on the card (relative to the campaign)")
    glass_panels: list[dict[str, float]] = Field(
        default_factory=list, description="curtain-wall glass (fieldwork.GlassPanel)"
    )


class TruthError(DocumentError):
    """A truth file that is missing, not JSON, of another kind or an unknown format version, or invalid."""


class CampaignTruth(VersionedDocument):
    """The hidden truth of a virtual campaign (``truth/truth.json``): a :class:`~solidkit.document.VersionedDocument`
    (``"kind": "campaign-truth"``). Format 4 is schema 3 on the document base; files of schema 3
    (``"kind": "solidkit-synth-campaign-truth"``, ``schema_version``) are read as format 4."""

    KIND: ClassVar[str] = "campaign-truth"
    FORMAT_VERSION: ClassVar[int] = FORMAT_VERSION
    ERROR: ClassVar[type[DocumentError]] = TruthError
    WHAT: ClassVar[str] = "truth file"

    conventions_version: int = CONVENTIONS_VERSION
    seed: int
    scenes_requested: int
    probes_requested: int
    card_dir: str = "card"
    config: CampaignConfig
    renderer: dict[str, Any]
    radiometry: dict[str, Any]
    scenes: list[SceneTruth]


def load_truth(path: str | os.PathLike) -> CampaignTruth:
    """Read and validate a truth file (formats: :class:`CampaignTruth`); one-line :class:`TruthError` else."""
    p = Path(path)
    if not p.is_file():
        raise TruthError(f"{p}: no such truth file")
    data = read_json_object(p, TruthError, "truth file")
    if data.get("kind") == _LEGACY_KIND:
        version = data.get("schema_version")
        if version not in _LEGACY_VERSIONS:
            raise TruthError(
                f"{p}: campaign truth schema version {version!r}; this solidkit reads format version "
                f"{FORMAT_VERSION} and the older schema versions {', '.join(map(str, _LEGACY_VERSIONS))}"
            )
        data = {
            "kind": CampaignTruth.KIND,
            "format_version": FORMAT_VERSION,
            **{k: v for k, v in data.items() if k not in ("kind", "schema_version")},
        }
    truth = CampaignTruth.from_dict(data, str(p))
    if truth.conventions_version != CONVENTIONS_VERSION:
        raise ConventionsError(f"{p}: written under conventions version {truth.conventions_version}")
    return truth
