"""Dual-fisheye lens profiles: the file format and the forward/inverse fisheye projection.

Profile format (a :class:`~solidkit.document.VersionedDocument`: JSON, ``format_version`` 1;
files written before it say ``schema_version`` 1 and are read the same)
------------------------------------------------------------------------------------------------
::

    {"kind": "lens", "format_version": 1,
     "model": "theta-v",                      # profile name
     "camera_models": ["RICOH THETA V"],      # EXIF models it applies to
     "source": "...",                         # citation of the facts used (or how it was measured)
     "reference_size": [5792, 2896],          # width, height of the dual-fisheye image (px)
     "parent": null,                          # the model profile a per-unit profile was refined from
     "lenses": [
       {"name": "front",
        "center": [1447.5, 1447.5],           # optical centre (px) in the reference image; pixel
                                              #   (x, y) has its centre at (x, y) (OpenCV, conventions §1)
        "poly": [k1, k3, k5, k7, k9],         # image height r(theta) = sum_i k_(2i+1) theta^(2i+1)
                                              #   (r in px at reference_size, theta in radians)
        "max_angle_deg": 100.0,               # largest incidence angle the lens images
        "ypr_deg": [0, 0, 0],                 # lens orientation in the camera frame (conventions §4)
        "table": {"theta_deg": [...], "r_px": [...]}   # optional: the design/measured table
       },
       {"name": "back", ..., "ypr_deg": [180, 0, 0]}],
     "residuals": {...},                      # optional: fit/refinement quality (units in the key names)
     "provenance": {...},                     # optional (shipped profiles cite ``source``): inputs (path,
                                              #   sha256), tool, versions, date (solidkit.document.Provenance)
     "notes": "..."}

Geometry
~~~~~~~~
- **Camera frame** = our axes (docs/conventions.md §1-2) attached to the body: x right, y down,
  z = the front lens axis. Ricoh's own axes (X right, Y front lens, Z up) map to it by
  :data:`solidkit.camera.metadata.RICOH_TO_OURS`.
- **Lens frame** = OpenCV's camera frame for that lens' image: x toward increasing image
  column, y toward increasing image row, z along the optical axis (outward). ``R_lens =
  rotation_from_ypr(*ypr_deg)`` maps lens-frame vectors to camera-frame vectors. The front
  lens is ``[0, 0, 0]``, the back lens looks the other way (``yaw = 180``); an image circle
  turned by 90° in the file (Theta S live/video layout) is a ``roll`` of ±90°.
- **Projection** (the ``cv2.fisheye`` family: odd polynomial in the incidence angle): a lens-frame
  direction ``d`` with ``theta = acos(d_z)`` and ``psi = atan2(d_y, d_x)`` lands at
  ``(cx + r(theta) cos psi, cy + r(theta) sin psi)``. A ``cv2.fisheye`` calibration
  (``fx = fy = f``, ``k1..k4``) is ``poly = [f, f k1, f k2, f k3, f k4]``; an omnidirectional
  (Mei) model is exported by tabulating its ``r(theta)`` and calling :meth:`LensModel.from_table`.

:meth:`LensProfile.scaled` rescales a profile to another image size (same aspect ratio):
centres as continuous coordinates ``(c + 0.5) s - 0.5``, radii ``r s``.
"""

from __future__ import annotations

import hashlib
import math
import os
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from solidkit.document import DocumentError, VersionedDocument
from solidkit.envmap.coords import rotation_from_ypr, ypr_from_rotation
from solidkit.envmap.perspective import scale_pixel_coordinates

__all__ = [
    "FORMAT_VERSION",
    "LensTable",
    "LensModel",
    "LensProfile",
    "LensProfileError",
    "fit_odd_poly",
    "load_profile",
    "list_profiles",
    "profile_for_metadata",
    "project",
    "unproject",
]

FORMAT_VERSION = 1
_PROFILE_DIR = "profiles"


class LensProfileError(DocumentError):
    """A lens profile is missing, malformed, of another schema version, or does not fit the image."""


class LensTable(BaseModel):
    """Image height vs incidence angle, as published or measured (kept for provenance)."""

    model_config = ConfigDict(allow_inf_nan=False)
    theta_deg: list[float]
    r_px: list[float]


def fit_odd_poly(theta_rad: Any, r_px: Any, degree: int = 9) -> list[float]:
    """Least-squares odd polynomial ``r = sum k_(2i+1) theta^(2i+1)`` (no constant term).

    Returns ``[k1, k3, ..., k_degree]`` (px per radian^n).
    """
    t = np.asarray(theta_rad, dtype=np.float64)
    r = np.asarray(r_px, dtype=np.float64)
    A = np.stack([t ** (2 * i + 1) for i in range((degree + 1) // 2)], axis=-1)
    scale = np.abs(A).max(axis=0)
    scale[scale == 0] = 1
    k, *_ = np.linalg.lstsq(A / scale, r, rcond=None)
    return [float(v) for v in k / scale]


class LensModel(BaseModel):
    """One fisheye lens of a dual-fisheye camera (see the module docstring for the frames)."""

    model_config = ConfigDict(allow_inf_nan=False)  # a NaN centre or angle would unwarp to a blank panorama
    name: str
    center: tuple[float, float] = Field(description="optical centre (px) at the profile's reference size")
    poly: list[float] = Field(description="odd polynomial r(theta) coefficients k1, k3, ... (px, theta in rad)")
    max_angle_deg: float = Field(gt=0, le=180)
    ypr_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    table: LensTable | None = None

    @field_validator("poly")
    @classmethod
    def _poly_nonempty(cls, v: list[float]) -> list[float]:
        if not v or v[0] <= 0 or not all(math.isfinite(x) for x in v):
            raise ValueError("poly must start with a positive k1 and be finite")
        return v

    @model_validator(mode="after")
    def _monotonic(self) -> LensModel:
        t = np.linspace(0.0, math.radians(self.max_angle_deg), 512)
        if np.any(np.diff(self.radius(t)) <= 0):
            raise ValueError(f"lens {self.name}: r(theta) is not increasing up to {self.max_angle_deg} deg")
        return self

    @classmethod
    def from_table(
        cls,
        name: str,
        center: tuple[float, float],
        theta_deg: Any,
        r_px: Any,
        *,
        ypr_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
        max_angle_deg: float | None = None,
        degree: int = 13,
    ) -> LensModel:
        """Fit the odd polynomial to a table of image height ``r_px`` vs incidence angle ``theta_deg``."""
        t = np.asarray(theta_deg, dtype=np.float64)
        poly = fit_odd_poly(np.radians(t), r_px, degree)
        return cls(
            name=name,
            center=center,
            poly=poly,
            max_angle_deg=float(max_angle_deg or t.max()),
            ypr_deg=tuple(ypr_deg),
            table=LensTable(theta_deg=list(map(float, t)), r_px=list(map(float, r_px))),
        )

    @property
    def rotation(self) -> np.ndarray:
        """``R_lens`` (3, 3): lens-frame vectors -> camera-frame vectors."""
        return _rotation(tuple(float(a) for a in self.ypr_deg)).copy()

    def radius(self, theta: Any) -> Any:
        """Image height r (px, reference size) at incidence angle ``theta`` (radians)."""
        t = np.asarray(theta, dtype=np.float64)
        t2 = t * t
        acc = np.zeros_like(t)
        for k in reversed(self.poly):
            acc = acc * t2 + k
        return acc * t

    def dradius(self, theta: Any) -> Any:
        """``dr/dtheta`` (px per radian)."""
        t = np.asarray(theta, dtype=np.float64)
        return sum((2 * i + 1) * k * t ** (2 * i) for i, k in enumerate(self.poly))

    def angle(self, r: Any) -> Any:
        """Inverse of :meth:`radius`: incidence angle (radians) of image height ``r`` (px).

        Dense-table interpolation then two Newton steps (error < 1e-9 rad inside the domain).
        Radii beyond ``r(max_angle)`` get the polynomial's continuation (callers mask them).
        """
        r = np.asarray(r, dtype=np.float64)
        tmax = math.radians(self.max_angle_deg)
        grid, vals = _dense_inverse(tuple(self.poly), tmax)
        t = np.interp(r, vals, grid)
        beyond = r > vals[-1]
        if np.any(beyond):
            t = np.where(beyond, tmax + (r - vals[-1]) / float(self.dradius(tmax)), t)
        for _ in range(2):
            t = t - (self.radius(t) - r) / np.maximum(self.dradius(t), 1e-9)
        return t

    def max_radius(self) -> float:
        return float(self.radius(math.radians(self.max_angle_deg)))


@lru_cache(maxsize=1024)
def _rotation(ypr_deg: tuple[float, float, float]) -> np.ndarray:
    return np.asarray(rotation_from_ypr(*(math.radians(a) for a in ypr_deg)), dtype=np.float64)


@lru_cache(maxsize=32)
def _dense_inverse(poly: tuple[float, ...], tmax: float) -> tuple[np.ndarray, np.ndarray]:
    grid = np.linspace(0.0, tmax, 4097)
    t2 = grid * grid
    acc = np.zeros_like(grid)
    for k in reversed(poly):
        acc = acc * t2 + k
    return grid, acc * grid


class LensProfile(VersionedDocument):
    """A dual-fisheye camera's lenses at a reference image size (format: module docstring)."""

    model_config = ConfigDict(extra="ignore")  # profiles from other tools may carry fields of their own
    KIND: ClassVar[str] = "lens"
    FORMAT_VERSION: ClassVar[int] = FORMAT_VERSION
    ERROR: ClassVar[type[DocumentError]] = LensProfileError
    WHAT: ClassVar[str] = "profile"

    model: str
    camera_models: list[str] = Field(default_factory=list)
    source: str
    reference_size: tuple[int, int]
    lenses: list[LensModel]
    parent: str | None = None
    residuals: dict[str, Any] = Field(default_factory=dict)
    notes: str = ""

    @field_validator("provenance", mode="before")
    @classmethod
    def _no_provenance(cls, v: Any) -> Any:
        return None if v == {} else v  # files written before the document base said {} for "none"

    @field_validator("lenses")
    @classmethod
    def _two_lenses(cls, v: list[LensModel]) -> list[LensModel]:
        if not v:
            raise ValueError("a lens profile needs at least one lens")
        return v

    def scaled(self, width: int, height: int) -> LensProfile:
        """This profile for a ``width x height`` image of the same layout (same aspect ratio, ±1 px)."""
        W, H = self.reference_size
        if (width, height) == (W, H):
            return self
        s = width / W
        if abs(height - H * s) > 1.0:
            raise LensProfileError(
                f"profile {self.model!r} is for {W}x{H} images (aspect {W / H:.4g}); got {width}x{height}"
            )
        lenses = []
        for lens in self.lenses:
            cx, cy = lens.center
            table = None
            if lens.table is not None:
                table = LensTable(theta_deg=lens.table.theta_deg, r_px=[r * s for r in lens.table.r_px])
            lenses.append(
                lens.model_copy(
                    update={
                        "center": (scale_pixel_coordinates(cx, s), scale_pixel_coordinates(cy, s)),
                        "poly": [k * s for k in lens.poly],
                        "table": table,
                    }
                )
            )
        return self.model_copy(update={"reference_size": (width, height), "lenses": lenses})

    def key(self) -> str:
        """Hash of the geometry (name, reference size, lenses): remap caches and products name the
        profile by it; notes, residuals and provenance do not change it."""
        geometry = self.model_dump_json(include={"model", "reference_size", "lenses"})
        return hashlib.sha256(geometry.encode()).hexdigest()[:16]


def _builtin_dir() -> Any:
    return resources.files("solidkit.camera").joinpath(_PROFILE_DIR)


def list_profiles() -> list[str]:
    """Names of the profiles shipped with solidkit."""
    return sorted(p.name[:-5] for p in _builtin_dir().iterdir() if p.name.endswith(".json"))


def load_profile(name_or_path: str | os.PathLike[str]) -> LensProfile:
    """A shipped profile by name (``theta-v``) or a profile JSON file (e.g. a per-unit ``unit.json``)."""
    s = str(name_or_path)
    p = Path(s)
    if p.suffix == ".json" or p.exists() or os.sep in s:
        if not p.is_file():
            raise LensProfileError(f"{p}: no such lens profile file")
        return LensProfile.load(p)
    res = _builtin_dir().joinpath(s + ".json")
    if not res.is_file():
        raise LensProfileError(f"unknown lens profile {s!r}; shipped: {', '.join(list_profiles())}")
    return LensProfile.from_json(res.read_text(), s)


def profile_for_metadata(model: str | None, width: int, height: int) -> LensProfile:
    """The shipped profile whose ``camera_models`` contain ``model`` and whose layout fits the size."""
    candidates = []
    for name in list_profiles():
        prof = load_profile(name)
        if model and model.strip() in prof.camera_models:
            W, H = prof.reference_size
            if abs(width / height - W / H) < 0.01:
                candidates.append(prof)
    if not candidates:
        raise LensProfileError(
            f"no shipped lens profile for camera {model!r} at {width}x{height}; pass --profile "
            f"({', '.join(list_profiles())} or a unit.json)"
        )
    return candidates[0]


def project(lens: LensModel, d_cam: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Forward model: camera-frame directions ``(..., 3)`` -> fisheye pixel coordinates.

    Returns ``(x, y, theta)``: pixel coordinates (OpenCV convention, reference size of the
    lens' profile) and the incidence angle (radians); directions with ``theta > max_angle``
    are outside the image (callers mask with ``theta <= radians(max_angle_deg)``).
    """
    d = np.asarray(d_cam, dtype=np.float64)
    dl = d @ lens.rotation  # = (R^T d) for row vectors
    n = np.linalg.norm(dl, axis=-1)
    theta = np.arccos(np.clip(dl[..., 2] / np.maximum(n, 1e-300), -1.0, 1.0))
    rho = np.hypot(dl[..., 0], dl[..., 1])
    r = lens.radius(theta)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(rho > 1e-12, r / np.where(rho > 1e-12, rho, 1.0), 0.0)
    x = lens.center[0] + dl[..., 0] * scale
    y = lens.center[1] + dl[..., 1] * scale
    return x, y, theta


def unproject(lens: LensModel, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
    """Inverse model: fisheye pixel coordinates -> camera-frame unit directions ``(..., 3)`` and theta."""
    dx = np.asarray(x, dtype=np.float64) - lens.center[0]
    dy = np.asarray(y, dtype=np.float64) - lens.center[1]
    r = np.hypot(dx, dy)
    theta = lens.angle(r)
    st = np.sin(theta)
    with np.errstate(invalid="ignore", divide="ignore"):
        ux = np.where(r > 1e-12, dx / np.where(r > 1e-12, r, 1.0), 0.0)
        uy = np.where(r > 1e-12, dy / np.where(r > 1e-12, r, 1.0), 0.0)
    dl = np.stack([st * ux, st * uy, np.cos(theta)], axis=-1)
    return dl @ lens.rotation.T, theta


def rotation_to_ypr_deg(R: Any) -> tuple[float, float, float]:
    """``ypr_deg`` of a lens rotation matrix (for exporting calibrations into a profile)."""
    y, p, r = ypr_from_rotation(np.asarray(R, dtype=np.float64))
    return (math.degrees(float(y)), math.degrees(float(p)), math.degrees(float(r)))
