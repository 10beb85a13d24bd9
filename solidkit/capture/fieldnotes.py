"""Field notes: what the field team writes down at a scene, in a small file on the card.

A scene folder may hold ``fieldnotes.toml`` (or ``fieldnotes.json``, the same fields, for a
tablet app that writes JSON). ``solidkit ingest`` reads it, keeps a read-only copy beside the
originals and records it in the manifest (:class:`solidkit.capture.manifest.Scene` and
:class:`~solidkit.capture.manifest.Probe`). The protocol that asks for it is
``docs/field-protocol.md``. Example::

    # CARD/scene01/fieldnotes.toml
    fieldnotes = 1                    # format version
    camera_position = "cam"           # the folder of the Theta shots taken at the photo camera's position
    photo = "IMG_0001.JPG"            # the photo the pixels refer to (optional when the scene has one photo)
    notes = "square north of the station; light wind"

    [photo_pose]                      # optional: read off the tripod's level and a compass
    pitch_deg = -4.5                  # conventions §4: positive tilts up (elevation increases)
    roll_deg = 0.0
    heading_deg = 213.0               # clockwise from north
    heading_ref = "true"              # or "magnetic"

    [probes.p01]
    pixel = [412.5, 388.0]            # [x, y] in full-resolution photo pixels, as marked on the tablet
    note = "asphalt, in the sun"

    [probes.p02]
    pixel = [130, 402]

A card that does not use scene folders (a camera's own ``DCIM/`` card) may carry one
card-level ``CARD/fieldnotes.toml`` with a table per scene id (``[scenes.<id>]``, the same
fields, ``[scenes.<id>.probes.p01]``...). The camera position is a probe id; without notes a
probe folder named ``cam`` or ``camera`` (any case) marks it.

Validation is strict (unknown keys are refused, so a typo such as ``pixle`` is not silently
ignored): a file that does not parse or validate is recorded with a one-line error naming the
file, and none of it is applied; the rest of the card is ingested as usual.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Literal

import tomllib
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from solidkit.errors import InputError, validation_message

__all__ = [
    "NOTES_NAMES",
    "CAMERA_FOLDERS",
    "PhotoPose",
    "ProbeNote",
    "FieldNotes",
    "CardNotes",
    "is_notes_file",
    "read_notes",
    "notes_text",
    "card_notes_template",
]

NOTES_NAMES = ("fieldnotes.toml", "fieldnotes.json")
CAMERA_FOLDERS = ("cam", "camera")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class PhotoPose(_Strict):
    """The photo camera's pose as the team read it off the tripod (degrees; any field may be absent)."""

    heading_deg: float | None = Field(None, ge=0.0, lt=360.0, description="clockwise from north")
    heading_ref: Literal["true", "magnetic"] = "true"
    pitch_deg: float | None = Field(None, ge=-90.0, le=90.0, description="conventions §4 (positive: tilts up)")
    roll_deg: float | None = Field(None, ge=-180.0, le=180.0)


class ProbeNote(_Strict):
    """One Theta position: where it stands in the photo, and a remark."""

    pixel: tuple[float, float] | None = Field(None, description="[x, y] full-resolution photo pixels")
    note: str | None = None

    @field_validator("pixel")
    @classmethod
    def _finite(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not all(math.isfinite(c) and c >= 0.0 for c in v):
            raise ValueError("pixel coordinates must be finite and >= 0")
        return v


class FieldNotes(_Strict):
    """The notes of one scene (module docstring)."""

    fieldnotes: Literal[1] = Field(1, description="format version")
    camera_position: str | None = Field(None, description="probe id (folder) of the shot at the photo camera")
    photo: str | None = Field(None, description="file name of the photo the pixels refer to")
    notes: str | None = None
    photo_pose: PhotoPose | None = None
    probes: dict[str, ProbeNote] = Field(default_factory=dict)


class CardNotes(_Strict):
    """Card-level notes: one :class:`FieldNotes` table per scene id."""

    fieldnotes: Literal[1] = 1
    scenes: dict[str, FieldNotes] = Field(default_factory=dict)


def is_notes_file(name: str) -> bool:
    """Is this file name a field notes file (any case)?"""
    return name.lower() in NOTES_NAMES


def notes_text(notes: FieldNotes) -> str:
    """``notes`` as TOML (what the synthetic campaign writes; readable back by :func:`read_notes`)."""

    def val(v: object) -> str:
        if isinstance(v, str):
            return json.dumps(v, ensure_ascii=False)  # a JSON string is a valid TOML basic string
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = [f"fieldnotes = {notes.fieldnotes}"]
    for key in ("camera_position", "photo", "notes"):
        if getattr(notes, key) is not None:
            lines.append(f"{key} = {val(getattr(notes, key))}")
    if notes.photo_pose is not None:
        lines += ["", "[photo_pose]"] + [
            f"{k} = {val(v)}" for k, v in notes.photo_pose.model_dump().items() if v is not None
        ]
    for pid, pn in notes.probes.items():
        lines += ["", f"[probes.{json.dumps(pid)}]"] + [
            f"{k} = {val(v)}" for k, v in pn.model_dump().items() if v is not None
        ]
    return "\n".join(lines) + "\n"


def _key(k: str) -> str:
    """``k`` as a TOML key: bare when it can be, else quoted."""
    return k if k and all(c.isascii() and (c.isalnum() or c in "-_") for c in k) else json.dumps(k)


def card_notes_template(scenes: dict[str, tuple[str | None, list[str]]]) -> str:
    """A card-level ``fieldnotes.toml`` to fill in for scenes ingested without notes.

    ``scenes`` maps a scene id to (its camera position if known, its position ids in shooting
    order). What the team must decide is left commented out, so the file is valid as it stands
    and applies nothing by guess: the camera position (suggested: the first position shot) and
    each other position's ``[x, y]`` full-resolution photo pixel.
    """
    lines = ["fieldnotes = 1"]
    for sid, (cam, positions) in scenes.items():
        lines.append(f"[scenes.{json.dumps(sid)}]")
        if cam is None and positions:
            lines.append(f"# camera_position = {json.dumps(positions[0])}  # the position shot at the photo camera")
        first = cam or (positions[0] if positions else None)
        lines += [f"# probes.{_key(p)}.pixel = [x, y]  # photo pixel" for p in positions if p != first]
    return "\n".join(lines) + "\n"


def read_notes(path: str | Path, *, card_level: bool = False) -> FieldNotes | CardNotes:
    """Parse and validate a field notes file (TOML, or JSON by its ``.json`` suffix).

    Raises :class:`InputError` with one line naming the file and the first problem.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InputError(f"{p.name}: unreadable ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8-sig")
        data = json.loads(text) if p.suffix.lower() == ".json" else tomllib.loads(text)
    except UnicodeDecodeError:
        raise InputError(f"{p.name}: not UTF-8 text") from None
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{p.name}: not valid {p.suffix.lower().lstrip('.').upper()} ({exc})") from None
    except RecursionError:  # arrays or tables nested past the parser's stack
        raise InputError(f"{p.name}: not valid {p.suffix.lower().lstrip('.').upper()} (nested too deep)") from None
    if not isinstance(data, dict):
        raise InputError(f"{p.name}: expected a table of fields at the top level")
    model = CardNotes if card_level else FieldNotes
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise InputError(f"{p.name}: {validation_message(exc)}") from None
    except RecursionError:
        raise InputError(f"{p.name}: nested too deep") from None
