"""The test-set manifest ``OUT/testset.json``: a versioned pydantic schema, readable without solidkit.

A test set is a folder::

    testset.json                         this manifest (:class:`TestSet`)
    scenes/<scene>/photo.png             the photo resized/cropped to the model input (320x240)
    scenes/<scene>/photo_full.<ext>      the original photo, byte for byte
    scenes/<scene>/sun_panorama.png      the low-exposure panorama the sun was labeled on,
                                         rotated into the photo's panorama frame
    scenes/<scene>/probes/<probe>/       ldr.png (256x128), ldr_full.png, hdr.exr / hdr_full.exr
                                         (when a bracket exists), saturation.png / saturation_full.png
    scenes/<scene>/camera/               the same for the capture at the photo camera's position
    profiles/<sha256>.json               calibration profiles used (by content hash)

Every path in the manifest is relative to the folder (POSIX). ``files`` holds the SHA-256 and
size of every file but ``testset.json``; ``dataset_version`` is derived from the content (the
manifest without that field, files' checksums included), so two builds of the same inputs
have the same version and are byte-identical.

Frames and units follow ``docs/conventions.md``: pixels are OpenCV pixel centres (``[x, y]``),
directions and panoramas are in the photo's **panorama frame** (gravity-aligned, forward = the
photo's optical axis projected on the horizontal plane), angles are degrees, rotations are
3x3 matrices acting on column vectors. The JSON Schema export is ``docs/testset.schema.json``
(:func:`json_schema`; a test keeps it in sync).
"""

from __future__ import annotations

import hashlib
import json
import math
from typing import Annotated, Any, Final, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator

__all__ = [
    "FORMAT",
    "SCHEMA_VERSION",
    "MODEL_INPUT_SIZE",
    "PROBE_SIZE",
    "Source",
    "SOURCE_RANK",
    "FileEntry",
    "Exposure",
    "GPS",
    "PhotoCapture",
    "ProbeCapture",
    "Sun",
    "Cue",
    "Alignment",
    "ProbeImages",
    "Probe",
    "CameraCapture",
    "Scene",
    "ProfileRef",
    "Inputs",
    "TestSet",
    "content_version",
    "json_schema",
    "canonical_json",
]

FORMAT: Final = "solidkit-testset"
SCHEMA_VERSION = 1
MODEL_INPUT_SIZE = (320, 240)  # width, height (paper §4)
PROBE_SIZE = (256, 128)  # width, height of the paper's local probes (§5.3)

Source = Literal["auto", "field_notes", "annotator", "reviewed"]
#: Which value wins when several exist: a higher rank replaces a lower one.
SOURCE_RANK: dict[str, int] = {"auto": 0, "field_notes": 1, "annotator": 2, "reviewed": 3}


def _check_matrix3(value: list[list[float]]) -> list[list[float]]:
    if len(value) != 3 or any(len(row) != 3 for row in value):
        raise ValueError("must be a 3x3 matrix (3 rows of 3 numbers)")
    if not all(math.isfinite(x) for row in value for x in row):
        raise ValueError("must be finite")
    return value


Matrix3 = Annotated[list[list[float]], AfterValidator(_check_matrix3)]
Pixel = tuple[float, float]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class FileEntry(_Model):
    """Checksum of one file of the test set."""

    sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="hex SHA-256 of the file's bytes")
    bytes: int = Field(ge=0, description="file size in bytes")


class Exposure(_Model):
    """One exposure: time (s), f-number and ISO; None where the file does not say."""

    exposure_time_s: float | None = None
    f_number: float | None = None
    iso: float | None = None


class GPS(_Model):
    lat_deg: float
    lon_deg: float
    alt_m: float | None = None


class PhotoCapture(_Model):
    """The photo's capture metadata (EXIF)."""

    original_sha256: str = Field(description="SHA-256 of the original photo file in the campaign")
    time_local: str | None = Field(None, description="EXIF DateTimeOriginal, camera clock, ISO 8601 without offset")
    utc_offset: str | None = Field(None, description="EXIF OffsetTimeOriginal, e.g. '+02:00'")
    gps: GPS | None = None
    make: str | None = None
    model: str | None = None
    exposure: Exposure = Field(default_factory=Exposure)
    focal_length_mm: float | None = None
    heading_deg: float | None = Field(
        None, description="compass heading of the optical axis (EXIF GPSImgDirection), from north"
    )


class ProbeCapture(_Model):
    """How a Theta position was captured (from the campaign manifest)."""

    time_local: str | None = Field(None, description="first shot's DateTimeOriginal, camera clock")
    camera_model: str | None = None
    shots: list[str] = Field(default_factory=list, description="SHA-256 of the original shots, capture order")
    bracket_exposures_s: list[float] = Field(default_factory=list, description="exposure times of the HDR bracket (s)")
    bracket_f_number: float | None = None
    bracket_iso: float | None = None
    sun_frame_exposure: Exposure | None = Field(None, description="the low-exposure sun frame's exposure")
    ldr_exposure: Exposure | None = Field(
        None, description="the exposure of the shot the LDR probe is made from (the protocol's: 1/2500 s)"
    )
    recorded_pitch_deg: float | None = Field(None, description="gravity sensor pitch of the Theta (conventions §7)")
    recorded_roll_deg: float | None = None


class Sun(_Model):
    """The sun in the photo's panorama frame, or ``found = false`` (overcast, occluded, night)."""

    found: bool
    azimuth_deg: float | None = Field(
        None, description="conventions §3: 0 = forward, positive to the right, [-180, 180)"
    )
    elevation_deg: float | None = Field(None, description="above the horizon, degrees")
    uncertainty_deg: float | None = Field(None, description="1-sigma angular uncertainty, degrees")
    direction: list[float] | None = Field(
        None, description="unit vector (x right, y down, z forward) of azimuth/elevation"
    )
    source: Source = Field(description="provenance: auto (detector), field_notes, annotator or reviewed")
    annotator: str | None = None
    label_version: int | None = Field(None, description="version of the label in the campaign's label store")
    flags: list[str] = Field(default_factory=list, description="open problems (a label still flagged for review, ...)")
    panorama: str | None = Field(
        None, description="the low-exposure panorama it was labeled on, in the photo's panorama frame"
    )
    panorama_capture: str | None = Field(None, description="id of the Theta position whose sun frame that is")
    panorama_exposure: Exposure | None = None

    @field_validator("direction")
    @classmethod
    def _unit(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and len(v) != 3:
            raise ValueError("direction must have 3 components")
        return v


class Cue(_Model):
    """One alignment cue (e.g. sun, features, compass): its yaw estimate, weight, and whether it was usable."""

    yaw_deg: float | None = None
    weight: float = 0.0
    ok: bool = False


class Alignment(_Model):
    """How a probe capture was rotated into the photo's panorama frame."""

    yaw_deg: float | None = Field(None, description="yaw of the capture's level frame in the photo's panorama frame")
    residual_deg: float | None = Field(None, description="disagreement of the cues with the chosen rotation, degrees")
    cues: dict[str, Cue] = Field(default_factory=dict)
    source: Source = Field(
        "auto", description="who set the rotation (a heading label in the store overrides the auto value)"
    )
    annotator: str | None = None
    flags: list[str] = Field(default_factory=list)


class ProbeImages(_Model):
    """The aligned panoramas of one capture (paths; HDR ones are null without a bracket)."""

    ldr: str = Field(description="256x128 sRGB PNG in the photo's panorama frame (the paper's format)")
    ldr_full: str = Field(description="full-resolution sRGB PNG, same frame")
    hdr: str | None = Field(None, description="256x128 linear EXR, same frame")
    hdr_full: str | None = Field(None, description="full-resolution linear EXR, same frame")
    saturation: str = Field(description="256x128 mask PNG: 255 where the LDR probe is clipped")
    saturation_full: str
    ldr_full_size: tuple[int, int] = Field(description="width, height of ldr_full")
    saturated_fraction: float = Field(
        ge=0.0, le=1.0, description="solid-angle-weighted share of clipped pixels (256x128)"
    )


class Probe(_Model):
    """A local light probe: a Theta capture at a point seen in the photo."""

    id: str
    pixel: Pixel = Field(description="[x, y] in the 320x240 photo (OpenCV pixel centres)")
    pixel_full: Pixel = Field(description="[x, y] in the full-resolution photo")
    pixel_source: Source
    pixel_annotator: str | None = None
    ldr: str = Field(description="path of the 256x128 LDR probe (= images.ldr)")
    hdr: str | None = Field(None, description="path of the 256x128 HDR probe or null (= images.hdr)")
    rotation: Matrix3 = Field(description="3x3, probe body frame -> the photo's panorama frame")
    alignment: Alignment
    images: ProbeImages
    capture: ProbeCapture = Field(default_factory=ProbeCapture)
    flags: list[str] = Field(default_factory=list)
    note: str | None = None


class CameraCapture(_Model):
    """The Theta capture at the photo camera's position (global lighting), aligned like a probe."""

    id: str
    rotation: Matrix3
    alignment: Alignment
    images: ProbeImages
    capture: ProbeCapture = Field(default_factory=ProbeCapture)


class Scene(_Model):
    id: str
    photo: str = Field(description="path of the photo at the model input size (320x240 PNG)")
    photo_full: str = Field(description="path of the original photo (byte-identical copy)")
    photo_size: tuple[int, int] = Field(description="width, height of photo")
    photo_full_size: tuple[int, int] = Field(description="width, height of photo_full")
    crop_box: tuple[int, int, int, int] = Field(
        description="x0, y0, width, height of the centre crop in photo_full before resizing"
    )
    K: Matrix3 = Field(description="3x3 intrinsics of photo (OpenCV pixel centres)")
    K_full: Matrix3 = Field(description="3x3 intrinsics of photo_full")
    K_source: str = Field(description="where K_full came from (camera profile, EXIF route, ...)")
    pitch_deg: float = Field(description="photo camera pitch in its panorama frame (conventions §4)")
    roll_deg: float
    heading_deg: float | None = Field(
        None, description="compass heading of the panorama frame's forward axis, from true north"
    )
    sun: Sun
    camera: CameraCapture | None = Field(None, description="the capture at the photo camera's position, if any")
    probes: list[Probe]
    capture: PhotoCapture
    flags: list[str] = Field(default_factory=list)
    notes: str | None = None


class ProfileRef(_Model):
    """A calibration profile used by the campaign, by content hash."""

    role: str = Field(description="response | lens | vignetting | camera")
    kind: str = Field(description="file (copied into profiles/) | shipped (named, part of solidkit) | builtin")
    name: str | None = None
    sha256: str | None = None
    path: str | None = Field(None, description="copy inside the test set (profiles/<sha256>.json)")


class Inputs(_Model):
    """What the test set was built from (content hashes; no absolute paths, no times)."""

    campaign: str = Field(description="the campaign folder's name")
    manifest_sha256: str
    alignment_sha256: str
    labels_sha256: str | None = Field(
        None, description="SHA-256 of the label store's canonical export; null without a store"
    )
    labels_used: int = 0


class TestSet(_Model):
    """``testset.json``."""

    format: Literal["solidkit-testset"] = FORMAT
    version: int = Field(SCHEMA_VERSION, description="schema version of this file")
    dataset_version: str = Field("", description="'sha256:<16 hex>' of the content (this file without this field)")
    conventions_version: int
    solidkit_version: str
    model_input_size: tuple[int, int] = MODEL_INPUT_SIZE
    probe_size: tuple[int, int] = PROBE_SIZE
    inputs: Inputs
    profiles: list[ProfileRef] = Field(default_factory=list)
    scenes: list[Scene]
    files: dict[str, FileEntry] = Field(description="every file of the test set but testset.json, by path")

    __test__ = False  # not a pytest class


def canonical_json(data: Any) -> str:
    """Sorted keys, 1-space indent, a final newline: the only way testset.json is written."""
    return json.dumps(data, sort_keys=True, indent=1, ensure_ascii=False, allow_nan=False) + "\n"


def content_version(testset: TestSet | dict[str, Any]) -> str:
    """``sha256:<16 hex>`` of the canonical JSON of the manifest without ``dataset_version``."""
    data = testset.model_dump(mode="json") if isinstance(testset, TestSet) else dict(testset)
    data.pop("dataset_version", None)
    return "sha256:" + hashlib.sha256(canonical_json(data).encode("utf-8")).hexdigest()[:16]


def json_schema() -> dict[str, Any]:
    """The JSON Schema of ``testset.json`` (what ``docs/testset.schema.json`` holds)."""
    schema = TestSet.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = f"https://solidkit/schemas/testset/v{SCHEMA_VERSION}.json"
    schema["title"] = "solidkit test set (testset.json)"
    return schema
