"""Versioned calibration profiles with provenance: the common base of every profile file.

A profile is a JSON document::

    {"kind": "response", "format_version": 1,
     "provenance": {"inputs": [{"path": ..., "sha256": ...}], "created": "2026-...Z",
                    "solidkit_version": "0.1.0", "conventions_version": 1, "tool": ..., "parameters": {...}},
     "residuals": {...},      # how good the fit is (units in the key names)
     ...}                     # the kind's own fields

The document machinery (atomic writes; loading checks the kind, the format version and the
conventions version and raises :class:`ProfileError`, one line at the CLI, on any mismatch or
malformed file) is :class:`solidkit.document.VersionedDocument`'s; a profile adds a required
provenance and its residuals.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Any, ClassVar

from pydantic import Field

from solidkit.document import (  # noqa: F401  (re-exported: the profiles' provenance is the documents')
    DocumentError,
    InputFile,
    Provenance,
    VersionedDocument,
    make_provenance,
    read_json_object,
)

__all__ = ["ProfileError", "InputFile", "Provenance", "Profile", "make_provenance", "load_calibration_profile"]


class ProfileError(DocumentError):
    """A calibration profile is missing, malformed, of another kind or of another format version."""


class Profile(VersionedDocument):
    """Base class of the calibration profiles (a :class:`~solidkit.document.VersionedDocument`):
    kind, format version, provenance (required) and residuals.

    Subclasses set ``KIND`` (and bump ``FORMAT_VERSION`` when their fields change incompatibly).
    """

    KIND: ClassVar[str] = "profile"
    ERROR: ClassVar[type[DocumentError]] = ProfileError
    WHAT: ClassVar[str] = "profile"

    provenance: Provenance
    residuals: dict[str, Any] = Field(default_factory=dict)


_KIND_MODULES = {
    "response": "solidkit.calibration.response",
    "colour": "solidkit.calibration.colour",
    "camera": "solidkit.calibration.camera",
    "fisheye": "solidkit.calibration.fisheye",
    "vignetting": "solidkit.calibration.vignetting",
}


def load_calibration_profile(path: str | os.PathLike) -> Profile:
    """Load any calibration profile, dispatching on its ``kind`` field."""
    path = Path(path)
    kind = read_json_object(path, ProfileError, "profile").get("kind")
    module = _KIND_MODULES.get(kind) if isinstance(kind, str) else None
    if module:
        importlib.import_module(module)
    for sub in _all_subclasses(Profile):
        if sub.KIND == kind:
            return sub.load(path)
    raise ProfileError(f"{path}: unknown profile kind {kind!r}")


def _all_subclasses(cls: type[Profile]) -> list[type[Profile]]:
    out = []
    for sub in cls.__subclasses__():
        out.append(sub)
        out.extend(_all_subclasses(sub))
    return out
