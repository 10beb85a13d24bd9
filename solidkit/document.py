"""Versioned JSON documents with provenance: the common base of every file solidkit writes for later reading.

A document is a JSON object::

    {"kind": "response", "format_version": 1,
     "provenance": {"inputs": [{"path": ..., "sha256": ...}], "created": "2026-...Z",
                    "solidkit_version": "0.1.0", "conventions_version": 1, "tool": ..., "parameters": {...}},
     ...}                     # the kind's own fields

A subclass of :class:`VersionedDocument` sets ``KIND`` and ``FORMAT_VERSION`` (bumped when its
fields change incompatibly) and the error it raises (``ERROR``, an
:class:`~solidkit.errors.InputError`: one line and exit code 2 at the CLI). Loading checks, in this
order, that the file is a JSON object, its ``kind``, its ``format_version`` (documents written
before this base used ``schema_version``: read as the same thing), the
``provenance.conventions_version`` (:class:`~solidkit.errors.ConventionsError`) and the fields
(pydantic; the message is :func:`~solidkit.errors.validation_message`). Files are written
atomically (:func:`solidkit.fsutil.atomic_write_text`).

Users: the calibration profiles (:class:`solidkit.calibration.profile.Profile`) and the lens
profiles (:class:`solidkit.camera.lens.LensProfile`).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from solidkit import __version__
from solidkit.envmap.coords import CONVENTIONS_VERSION
from solidkit.errors import ConventionsError, InputError, validation_message
from solidkit.fsutil import atomic_write_text, sha256_file

__all__ = ["DocumentError", "InputFile", "Provenance", "make_provenance", "VersionedDocument", "read_json_object"]


class DocumentError(InputError):
    """A document is missing, not JSON, of another kind or format version, or invalid."""


class InputFile(BaseModel):
    """One input of a computation: its path as given and the SHA-256 of its content."""

    path: str
    sha256: str


class Provenance(BaseModel):
    """Where a document came from: inputs and their hashes, date, software versions, parameters."""

    inputs: list[InputFile] = Field(default_factory=list)
    created: str = Field(description="UTC timestamp, ISO 8601")
    solidkit_version: str
    conventions_version: int = CONVENTIONS_VERSION
    tool: str = Field(description="the function or command that produced the document")
    parameters: dict[str, Any] = Field(default_factory=dict, description="settings used")


def make_provenance(
    inputs: list[str | os.PathLike[str]] | tuple[str | os.PathLike[str], ...] = (), tool: str = "", **parameters: Any
) -> Provenance:
    """Provenance of a document computed now from ``inputs`` (files hashed with SHA-256)."""
    files = [InputFile(path=str(p), sha256=sha256_file(p)) for p in inputs]
    now = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")
    return Provenance(inputs=files, created=now, solidkit_version=__version__, tool=tool, parameters=parameters)


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):  # e.g. 1e400: Python's json makes it inf
        raise ValueError(f"{text} is out of the float range")
    return value


def read_json_object(
    path: str | os.PathLike[str],
    error: type[InputError] = DocumentError,
    what: str = "document",
    *,
    finite: bool = False,
) -> dict[str, Any]:
    """The JSON object in ``path``; ``error`` (one line) when the file is missing, unreadable, nested too deep
    to parse or not an object. ``finite``: ``NaN`` / ``Infinity`` (which Python's json accepts, JSON does not)
    and numbers past the float range (``1e400``) are an error too (documents written with ``allow_nan=False``)."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: no such {what} file")
    try:
        text = path.read_text(encoding="utf-8")
        data = json.loads(text, parse_constant=_no_constant, parse_float=_finite_float) if finite else json.loads(text)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise error(f"{path}: not a JSON {what} ({exc})") from None
    except RecursionError:
        raise error(f"{path}: not a JSON {what} (nested too deep)") from None
    if not isinstance(data, dict):
        raise error(f"{path}: a {what} is a JSON object")
    return data


M = TypeVar("M", bound=BaseModel)


def validate_versioned(
    path: str | os.PathLike[str],
    data: dict[str, Any],
    model: type[M],
    *,
    kind_key: str,
    kind: str,
    version_key: str,
    version: int,
    what: str,
    error: type[InputError] = InputError,
) -> M:
    """``data`` (read from ``path``) as ``model`` once its kind, format version and conventions version are checked.

    For documents whose field names predate :class:`VersionedDocument` (the alignment, the test set manifest):
    the same checks in the same order, each a one-line ``error`` (:class:`ConventionsError` for conventions).
    """
    if data.get(kind_key) != kind:
        raise error(f"{path}: not a solidkit {what}")
    if data.get(version_key) != version:
        raise error(f"{path}: {what} schema version {data.get(version_key)!r}; this solidkit reads {version}")
    if data.get("conventions_version") != CONVENTIONS_VERSION:
        raise ConventionsError(f"{path}: written under conventions version {data.get('conventions_version')}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise error(f"{path}: invalid {what}: {validation_message(exc)}") from None


D = TypeVar("D", bound="VersionedDocument")


class VersionedDocument(BaseModel):
    """Base of the versioned documents: ``kind``, ``format_version`` and ``provenance`` (module docstring)."""

    model_config = ConfigDict(extra="forbid")
    KIND: ClassVar[str] = "document"
    FORMAT_VERSION: ClassVar[int] = 1
    ERROR: ClassVar[type[InputError]] = DocumentError
    WHAT: ClassVar[str] = "document"

    kind: str = ""
    format_version: int = 0
    provenance: Provenance | None = None

    def model_post_init(self, __context: Any) -> None:  # noqa: D401
        if not self.kind:
            self.kind = self.KIND
        if not self.format_version:
            self.format_version = self.FORMAT_VERSION

    def to_json(self) -> str:
        """The document as indented JSON text (what :meth:`save` writes)."""
        return self.model_dump_json(indent=2) + "\n"

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the document as indented JSON, atomically; returns the path."""
        path = Path(path)
        atomic_write_text(path, self.to_json())
        return path

    @classmethod
    def load(cls: type[D], path: str | os.PathLike[str]) -> D:
        """Read and validate a document of this kind; raises ``ERROR`` when it is not one."""
        return cls.from_dict(read_json_object(path, cls.ERROR, cls.WHAT), str(path))

    @classmethod
    def from_json(cls: type[D], text: str, name: str = "document") -> D:
        """:meth:`from_dict` of JSON text (e.g. a packaged resource)."""
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise cls.ERROR(f"{name}: not a JSON {cls.WHAT} ({exc})") from None
        return cls.from_dict(data, name)

    @classmethod
    def from_dict(cls: type[D], data: Any, name: str = "document") -> D:
        """Validate a decoded document: kind, format version, conventions version, then the fields."""
        if not isinstance(data, dict):
            raise cls.ERROR(f"{name}: a {cls.WHAT} is a JSON object")
        kind = data.get("kind")
        if kind is None:
            raise cls.ERROR(f"{name}: has no 'kind' field, expected a {cls.KIND!r} {cls.WHAT}")
        if kind != cls.KIND:
            raise cls.ERROR(f"{name}: is a {kind!r} {cls.WHAT}, expected {cls.KIND!r}")
        if "format_version" not in data and "schema_version" in data:  # written before this base existed
            data = {("format_version" if k == "schema_version" else k): v for k, v in data.items()}
        if data.get("format_version") != cls.FORMAT_VERSION:
            raise cls.ERROR(
                f"{name}: {cls.KIND} {cls.WHAT} format version {data.get('format_version')!r}; "
                f"this solidkit reads version {cls.FORMAT_VERSION}"
            )
        provenance = data.get("provenance")
        conv = provenance.get("conventions_version") if isinstance(provenance, dict) else None
        if conv is not None and conv != CONVENTIONS_VERSION:
            raise ConventionsError(f"{name}: written under conventions version {conv}, this is {CONVENTIONS_VERSION}")
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise cls.ERROR(f"{name}: invalid {cls.KIND} {cls.WHAT}: {validation_message(exc)}") from None
