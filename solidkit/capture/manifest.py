"""The campaign manifest (``CAMPAIGN_DIR/manifest.json``): a versioned pydantic schema.

:class:`Manifest` records every original (content-addressed :class:`Shot`), the grouping into
:class:`Scene` / :class:`Probe` / :class:`Bracket`, the field notes read from the cards
(:class:`FieldNotesRecord`, :mod:`solidkit.capture.fieldnotes`), the derived :class:`Product`
files and the per-file errors. It holds no timestamps of the run: it is a pure function of the
cards' files, the field notes and the grouping parameters (see :mod:`solidkit.capture.campaign`).

The manifest is a :class:`~solidkit.document.VersionedDocument` (``"kind": "manifest"``,
``format_version``; no ``provenance``: the manifest carries no run timestamp, its
``solidkit_version``/``conventions_version`` say what wrote it). Format history: version 1 (no
field notes, roles or photo pose) is read and upgraded in memory (the new fields take their
defaults until the next ``ingest`` regroups); version 2 adds ``Scene.camera_probe``,
``Scene.notes``, ``Scene.photo``, ``Scene.photo_heading_deg`` / ``photo_pitch_deg`` /
``photo_roll_deg`` (+ their sources), ``Scene.warnings``, ``Probe.role``, ``Probe.photo_pixel``,
``Probe.note`` and ``Manifest.fieldnotes``; version 3 is version 2 on the document base (``kind``,
``format_version`` instead of ``schema_version``). Versions 1 and 2 (files without ``kind``) are
read; any other version is refused with a one-line :class:`ManifestError`.
"""

from __future__ import annotations

import os
from datetime import datetime
from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field

from solidkit import __version__
from solidkit.document import DocumentError, VersionedDocument, read_json_object
from solidkit.envmap.coords import CONVENTIONS_VERSION
from solidkit.fsutil import atomic_write_text

__all__ = [
    "SCHEMA_VERSION",
    "FORMAT_VERSION",
    "ManifestError",
    "MANIFEST_NAME",
    "ShotKind",
    "GroupingParams",
    "SourceRef",
    "SkippedFile",
    "Shot",
    "Bracket",
    "Probe",
    "Scene",
    "Product",
    "FileError",
    "FieldNotesRecord",
    "Manifest",
    "load_manifest",
    "save_manifest",
]

FORMAT_VERSION = 3
SCHEMA_VERSION = FORMAT_VERSION  # the name before the document base
_LEGACY_VERSIONS = (1, 2)  # files with "schema_version" and no "kind"
MANIFEST_NAME = "manifest.json"
ShotKind = Literal["photo", "probe", "low_exposure", "bracket_member"]


class GroupingParams(BaseModel):
    """How shots are grouped (seconds). Stored in the manifest; changing them regroups."""

    scene_gap_s: float = 600.0
    probe_gap_s: float = 45.0
    bracket_gap_s: float = 10.0
    low_exposure_max_s: float = 1.0 / 4000.0


class SourceRef(BaseModel):
    """Where a shot was found: card directory, path relative to it (POSIX), size and mtime."""

    card: str
    path: str
    size: int
    mtime_ns: int


class SkippedFile(SourceRef):
    """A card entry that is not ingested (unrelated file, link, special file, hidden folder) and why."""

    reason: str = ""


class Shot(BaseModel):
    """One original capture (content-addressed) with its metadata and its place in the campaign."""

    sha256: str
    original: str = Field(description="path relative to the campaign directory")
    size: int
    file_format: str
    sources: list[SourceRef]
    metadata: dict[str, Any] = Field(description="solidkit.camera.metadata.CaptureMetadata, as JSON")
    layout_scene: str | None = Field(None, description="scene id given by the card's folder layout")
    layout_probe: str | None = Field(None, description="probe id (or 'photo') given by the folder layout")
    kind: ShotKind | None = None
    scene: str | None = None
    probe: str | None = None
    bracket: str | None = None


class Bracket(BaseModel):
    """An exposure bracket: member shots (capture order) and their exposure times (s)."""

    id: str
    shots: list[str]
    exposure_times: list[float | None]


class Probe(BaseModel):
    """A Theta position: the shots taken there, its role and what the field notes say about it."""

    id: str
    shots: list[str]
    role: Literal["camera", "probe"] = Field(
        "probe", description="'camera': taken at the photo camera's position (field notes or a folder named 'cam')"
    )
    photo_pixel: list[float] | None = Field(
        None,
        description="[x, y] full-resolution pixels of the scene's photo where the probe stands, as the field "
        "team marked it (field notes; not refined)",
    )
    note: str | None = Field(None, description="the field team's remark on this position")
    brackets: list[Bracket] = Field(default_factory=list)
    sun_frame: str | None = Field(None, description="sha256 of the shot kept as the sun frame")
    warnings: list[str] = Field(default_factory=list)


class Scene(BaseModel):
    """A scene: its photos and Theta positions; times are the camera clock (naive)."""

    id: str
    grouping: Literal["folder", "time", "undated"]
    start: datetime | None = None
    end: datetime | None = None
    photos: list[str] = Field(default_factory=list)
    photo: str | None = Field(
        None,
        description="sha256 of the scene's reference photo (named by the field notes, else the first photo): "
        "the photo the probe pixels and the photo pose refer to",
    )
    camera_probe: str | None = Field(None, description="id of the Theta position at the photo camera's position")
    photo_heading_deg: float | None = Field(
        None, description="the photo camera's heading, degrees clockwise from north (EXIF GPSImgDirection, else notes)"
    )
    photo_heading_ref: Literal["true", "magnetic"] | None = Field(None, description="north of photo_heading_deg")
    photo_pitch_deg: float | None = Field(None, description="photo camera pitch, degrees (conventions §4), if known")
    photo_roll_deg: float | None = Field(None, description="photo camera roll, degrees (conventions §4), if known")
    photo_pose_source: dict[str, str] = Field(
        default_factory=dict, description="where each of heading/pitch/roll came from (exif field or 'fieldnotes')"
    )
    notes: str | None = Field(None, description="the field team's remarks on the scene (field notes)")
    fieldnotes: str | None = Field(None, description="sha256 of the field notes file applied to this scene")
    probes: list[Probe] = Field(default_factory=list)
    warnings: list[str] = Field(default_factory=list)


class Product(BaseModel):
    """A derived file: reproducible from its inputs, recipe and solidkit version."""

    id: str
    kind: Literal["hdr", "sun_frame"]
    scene: str
    probe: str
    inputs: list[str] = Field(description="sha256 of the originals, in order")
    path: str | None = Field(None, description="relative to the campaign directory")
    sha256: str | None = None
    layout: str = Field("unknown", description="image type of the product's pixels")
    exposure_time: float | None = Field(None, description="seconds (sun frame; HDR: first frame)")
    f_number: float | None = None
    iso: float | None = None
    recipe: dict[str, Any] = Field(default_factory=dict)
    recipe_hash: str = ""
    solidkit_version: str = ""
    stats: dict[str, Any] = Field(default_factory=dict)
    error: str | None = None
    error_transient: bool = Field(
        False,
        description="the error came from the environment (disk full, I/O): the product is built again on the next run",
    )


class FileError(BaseModel):
    """A card file that could not be ingested, and why."""

    card: str
    path: str
    size: int
    mtime_ns: int
    message: str


class FieldNotesRecord(BaseModel):
    """A field notes file found on a card (:mod:`solidkit.capture.fieldnotes`), parsed or refused."""

    card: str
    path: str = Field(description="relative to the card (POSIX)")
    sha256: str
    original: str | None = Field(None, description="its read-only copy, relative to the campaign directory")
    scene: str | None = Field(None, description="the scene folder it lies in; None for a card-level file")
    notes: dict[str, Any] | None = Field(None, description="the validated notes (FieldNotes / CardNotes as JSON)")
    error: str | None = Field(None, description="why the file was refused (then nothing of it is applied)")


class ManifestError(DocumentError):
    """A manifest.json that is not JSON, of another kind or an unknown format version, or invalid."""


class Manifest(VersionedDocument):
    """The campaign manifest (``manifest.json``)."""

    model_config = ConfigDict(extra="forbid")
    KIND: ClassVar[str] = "manifest"
    FORMAT_VERSION: ClassVar[int] = FORMAT_VERSION
    ERROR: ClassVar[type[DocumentError]] = ManifestError
    WHAT: ClassVar[str] = "manifest"

    solidkit_version: str = ""
    conventions_version: int = 0
    grouping: GroupingParams = Field(default_factory=GroupingParams)
    response: dict[str, Any] = Field(
        default_factory=lambda: {"kind": "auto"},
        description="{kind: file, path, sha256} (--response), or {kind: auto}: each bracket's curve estimated from "
        "its frames (3+), else sRGB assumed (the product's stats say which)",
    )
    lens_profile: dict[str, Any] | None = Field(
        None,
        description=(
            "per-unit lens profile overriding the model default: {kind: file, path, sha256} or {kind: shipped, name}"
        ),
    )
    vignetting: dict[str, Any] | None = Field(None, description="vignetting profile {kind: file, path, sha256}")
    cards: list[str] = Field(default_factory=list)
    shots: list[Shot] = Field(default_factory=list)
    fieldnotes: list[FieldNotesRecord] = Field(default_factory=list)
    scenes: list[Scene] = Field(default_factory=list)
    products: list[Product] = Field(default_factory=list)
    errors: list[FileError] = Field(default_factory=list)
    skipped: list[SkippedFile] = Field(default_factory=list, description="card entries not ingested, with the reason")

    @property
    def schema_version(self) -> int:
        """The format version (its name before the document base)."""
        return self.format_version

    def shot(self, sha: str) -> Shot:
        for s in self.shots:
            if s.sha256 == sha:
                return s
        raise KeyError(sha)

    def scene(self, scene_id: str) -> Scene:
        for sc in self.scenes:
            if sc.id == scene_id:
                return sc
        raise KeyError(scene_id)


def load_manifest(campaign_dir: str | os.PathLike) -> Manifest:
    """Read and validate ``CAMPAIGN_DIR/manifest.json`` (an empty manifest when absent).

    A version-1 or -2 manifest (written before the document base: ``schema_version``, no ``kind``) is
    upgraded in memory (new fields at their defaults); other versions raise :class:`ManifestError`.
    """
    path = Path(campaign_dir) / MANIFEST_NAME
    if not path.exists():
        return Manifest(solidkit_version=__version__, conventions_version=CONVENTIONS_VERSION)
    data = read_json_object(path, ManifestError, "manifest")
    if "kind" not in data:
        version = data.get("schema_version")
        if version not in _LEGACY_VERSIONS:
            raise ManifestError(
                f"{path}: manifest schema version {version!r}; this solidkit reads format version "
                f"{FORMAT_VERSION} and the older schema versions {', '.join(map(str, _LEGACY_VERSIONS))}"
            )
        data = {
            "kind": Manifest.KIND,
            "format_version": FORMAT_VERSION,
            **{k: v for k, v in data.items() if k != "schema_version"},
        }
        if isinstance(data.get("response"), dict) and data["response"].get("kind") == "srgb_inverse":
            data["response"] = {"kind": "auto"}  # version 1 silently assumed sRGB; now it is estimated or warned
    return Manifest.from_dict(data, str(path))


def save_manifest(campaign: Path, manifest: Manifest) -> None:
    """Write the manifest atomically (readable by all, like the products)."""
    atomic_write_text(campaign / MANIFEST_NAME, manifest.model_dump_json(indent=1) + "\n")
