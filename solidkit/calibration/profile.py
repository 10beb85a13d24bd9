"""Versioned calibration profiles with provenance: the common base of every profile file.

A profile is a JSON document::

    {"kind": "response", "format_version": 1,
     "provenance": {"inputs": [{"path": ..., "sha256": ...}], "created": "2026-...Z",
                    "solidkit_version": "0.1.0", "conventions_version": 1, "tool": ..., "parameters": {...}},
     "residuals": {...},      # how good the fit is (units in the key names)
     ...}                     # the kind's own fields

Files are written atomically (:func:`solidkit.fsutil.atomic_write_text`); loading checks the
kind, the format version and the conventions version and raises :class:`ProfileError`
(one line at the CLI) on any mismatch or malformed file.
"""

from __future__ import annotations

import datetime as _dt
import importlib
import json
import os
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from solidkit.envmap.coords import CONVENTIONS_VERSION
from solidkit.errors import ConventionsError, InputError, validation_message
from solidkit.fsutil import atomic_write_text, sha256_file

__all__ = ["ProfileError", "InputFile", "Provenance", "Profile", "make_provenance", "load_profile"]


class ProfileError(InputError):
    """A calibration profile is missing, malformed, of another kind or of another format version."""


class InputFile(BaseModel):
    """One input of a calibration: its path as given and the SHA-256 of its content."""

    path: str
    sha256: str


class Provenance(BaseModel):
    """Where a profile came from: inputs and their hashes, date, software versions, parameters."""

    inputs: list[InputFile] = Field(default_factory=list)
    created: str = Field(description="UTC timestamp, ISO 8601")
    solidkit_version: str
    conventions_version: int = CONVENTIONS_VERSION
    tool: str = Field(description="the function or command that produced the profile")
    parameters: dict[str, Any] = Field(default_factory=dict, description="settings used by the fit")


def make_provenance(inputs: list[str | os.PathLike] | tuple = (), tool: str = "", **parameters: Any) -> Provenance:
    """Provenance for a profile computed now from ``inputs`` (files hashed with SHA-256)."""
    from solidkit import __version__

    files = [InputFile(path=str(p), sha256=sha256_file(p)) for p in inputs]
    now = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")
    return Provenance(inputs=files, created=now, solidkit_version=__version__, tool=tool, parameters=parameters)


P = TypeVar("P", bound="Profile")


class Profile(BaseModel):
    """Base class of the calibration profiles: kind, format version, provenance and residuals.

    Subclasses set ``KIND`` (and bump ``FORMAT_VERSION`` when their fields change incompatibly).
    """

    model_config = ConfigDict(extra="forbid")
    KIND: ClassVar[str] = "profile"
    FORMAT_VERSION: ClassVar[int] = 1

    kind: str = ""
    format_version: int = 0
    provenance: Provenance
    residuals: dict[str, Any] = Field(default_factory=dict)

    def model_post_init(self, __context: Any) -> None:  # noqa: D401
        if not self.kind:
            self.kind = self.KIND
        if not self.format_version:
            self.format_version = self.FORMAT_VERSION

    def save(self, path: str | os.PathLike) -> Path:
        """Write the profile as indented JSON, atomically; returns the path."""
        path = Path(path)
        atomic_write_text(path, self.model_dump_json(indent=2) + "\n")
        return path

    @classmethod
    def load(cls: type[P], path: str | os.PathLike) -> P:
        """Read and validate a profile of this kind; raises :class:`ProfileError` when it is not one."""
        path = Path(path)
        if not path.is_file():
            raise ProfileError(f"{path}: no such profile file")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ProfileError(f"{path}: not a JSON profile ({exc})") from None
        return cls.from_dict(data, str(path))

    @classmethod
    def from_dict(cls: type[P], data: Any, name: str = "profile") -> P:
        """Validate a decoded profile document (see :meth:`load`)."""
        if not isinstance(data, dict):
            raise ProfileError(f"{name}: a profile is a JSON object")
        kind = data.get("kind")
        if kind != cls.KIND:
            raise ProfileError(f"{name}: is a {kind!r} profile, expected {cls.KIND!r}")
        if data.get("format_version") != cls.FORMAT_VERSION:
            raise ProfileError(
                f"{name}: {cls.KIND} profile format version {data.get('format_version')!r}; "
                f"this solidkit reads version {cls.FORMAT_VERSION}"
            )
        conv = (data.get("provenance") or {}).get("conventions_version")
        if conv is not None and conv != CONVENTIONS_VERSION:
            raise ConventionsError(f"{name}: written under conventions version {conv}, this is {CONVENTIONS_VERSION}")
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise ProfileError(f"{name}: invalid {cls.KIND} profile: {validation_message(exc)}") from None


_KIND_MODULES = {
    "response": "solidkit.calibration.response",
    "colour": "solidkit.calibration.colour",
    "camera": "solidkit.calibration.camera",
    "fisheye": "solidkit.calibration.fisheye",
    "vignetting": "solidkit.calibration.vignetting",
}


def load_profile(path: str | os.PathLike) -> Profile:
    """Load any calibration profile, dispatching on its ``kind`` field."""
    path = Path(path)
    try:
        kind = json.loads(path.read_text(encoding="utf-8")).get("kind")
    except (OSError, ValueError, AttributeError) as exc:
        raise ProfileError(f"{path}: not a JSON profile ({exc})") from None
    module = _KIND_MODULES.get(kind)
    if module:
        importlib.import_module(module)
    for sub in _all_subclasses(Profile):
        if sub.KIND == kind:
            return sub.load(path)
    raise ProfileError(f"{path}: unknown profile kind {kind!r}")


def _all_subclasses(cls: type) -> list[type]:
    out = []
    for sub in cls.__subclasses__():
        out.append(sub)
        out.extend(_all_subclasses(sub))
    return out
