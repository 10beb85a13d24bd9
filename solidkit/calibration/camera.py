"""Photo-camera intrinsics K (the limited-FOV photo) and resizing/cropping to the model input.

Conventions §1: OpenCV pixel centres (the pixel in column ``x`` has its centre at ``x``), so an
ideal W×H camera has ``cx = (W − 1)/2``. Under a resize by ``s`` (cv2.resize samples the source
at ``(x' + 0.5)/s − 0.5``) the principal point moves as ``cx' = (cx + 0.5)·s − 0.5`` and the
focal length as ``fx' = fx·s``; a crop at ``(x0, y0)`` subtracts the offset.

Sources of K, best first:

1. a checkerboard calibration (:func:`calibrate_checkerboard`, ``cv2.calibrateCamera``);
2. EXIF ``FocalLength`` with ``FocalPlaneXResolution`` (pixels per mm on the sensor);
3. EXIF ``FocalLength`` with the sensor width from :data:`SENSOR_WIDTH_MM` (by camera model);
4. EXIF ``FocalLengthIn35mmFilm`` (35 mm-equivalent, defined on the 43.27 mm diagonal);
5. a known horizontal field of view (e.g. a perspective crop of a Theta panorama: its K is
   the crop's, given by the FOV it was rendered with; a 360° camera's own stills are
   equirectangular or fisheye and have no pinhole K, so they are refused without ``fov_deg``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import cast

import cv2
import numpy as np
from pydantic import Field

from solidkit.calibration.boards import BoardView, detect_views
from solidkit.calibration.profile import Profile, make_provenance
from solidkit.camera.metadata import CaptureMetadata, read_metadata
from solidkit.envmap.io import imread
from solidkit.envmap.perspective import ideal_intrinsics, intrinsics_from_fov, scale_intrinsics
from solidkit.errors import InputError, SolidkitError

__all__ = [
    "MODEL_INPUT_SIZE",
    "SENSOR_WIDTH_MM",
    "CameraProfile",
    "IntrinsicsError",
    "intrinsics_from_exif",
    "sensor_width_from_table",
    "crop_intrinsics",
    "center_crop_box",
    "resize_crop",
    "calibrate_checkerboard",
    "calibrate_camera_from_photo",
    "calibrate_camera_from_board",
]

MODEL_INPUT_SIZE = (320, 240)  # width, height of SOLID-Net's input (paper §4)
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)

#: Sensor width (mm) by EXIF model for cameras whose EXIF lacks FocalPlaneXResolution.
#: Public spec-sheet values (1/2.3" ≈ 6.17 mm; 1" ≈ 13.2 mm; APS-C Canon 22.3 mm).
SENSOR_WIDTH_MM: dict[str, float] = {
    "Canon EOS 5D Mark II": 36.0,
    "Canon EOS 5D Mark III": 36.0,
    "Canon EOS Kiss X4": 22.3,
    "Canon EOS 550D": 22.3,
    "iPhone 11": 5.6,  # wide camera, 1/2.55"
    "iPhone 12": 5.6,
    "iPhone 13": 7.0,
    "iPhone X": 4.8,
    "Pixel 4": 5.6,
}


class IntrinsicsError(SolidkitError):
    """K cannot be determined (no focal length, unknown sensor) or the calibration failed."""


class CameraProfile(Profile):
    """Photo-camera intrinsics at the native size and at the model's input size."""

    KIND = "camera"
    source: str = Field(
        description=(
            "checkerboard | charuco | exif-focal-plane | exif-sensor-width | exif-sensor-table | exif-35mm | fov"
        )
    )
    image_size: tuple[int, int] = Field(description="width, height of the native image (px)")
    K: list[list[float]] = Field(description="3x3 intrinsics at image_size (OpenCV pixel centres)")
    dist: list[float] = Field(default_factory=list, description="OpenCV distortion (k1, k2, p1, p2, k3) if calibrated")
    model_input_size: tuple[int, int] = MODEL_INPUT_SIZE
    model_input_K: list[list[float]] = Field(description="K after resize_crop to model_input_size")
    crop_box: tuple[int, int, int, int] = Field(description="x0, y0, width, height of the centre crop (native px)")
    hfov_deg: float
    vfov_deg: float
    camera_model: str | None = None

    def matrix(self, model_input: bool = False) -> np.ndarray:
        return np.asarray(self.model_input_K if model_input else self.K, dtype=np.float64)


def intrinsics_from_exif(info: CaptureMetadata, sensor_width_mm: float | None = None) -> tuple[np.ndarray, str]:
    """K from EXIF focal geometry (square pixels, centred principal point); returns ``(K, source)``.

    ``info``: the photo's metadata (:func:`solidkit.camera.metadata.read_metadata`; its
    ``focal_length_mm``, ``focal_plane_px_per_mm``, ``exif_width``, ``focal_length_35mm``,
    ``make``/``model`` and image size).

    ``sensor_width_mm`` overrides the table lookup. Raises :class:`IntrinsicsError` when no
    route applies (no focal length, no focal-plane resolution, unknown model, no 35 mm value).
    """
    W, H = info.width, info.height
    if not W or not H:
        raise IntrinsicsError("EXIF intrinsics need the image size")
    f = info.focal_length_mm
    if f and sensor_width_mm:
        return ideal_intrinsics(W, H, f * W / sensor_width_mm), "exif-sensor-width"
    if f and info.focal_plane_px_per_mm:
        # FocalPlaneXResolution refers to the image size the camera recorded; rescale if resized.
        recorded_w = info.exif_width or W
        return ideal_intrinsics(W, H, f * info.focal_plane_px_per_mm[0] * W / recorded_w), "exif-focal-plane"
    table_width = sensor_width_from_table(info.make, info.model)
    if f and table_width:
        # the long side of the sensor is its width: rotate for portrait images
        return ideal_intrinsics(W, H, f * max(W, H) / table_width), "exif-sensor-table"
    if info.focal_length_35mm:
        return ideal_intrinsics(W, H, info.focal_length_35mm * math.hypot(W, H) / FULL_FRAME_DIAGONAL_MM), "exif-35mm"
    missing = "FocalLength" if not f else f"the sensor size of {info.model!r} (pass --sensor-width-mm)"
    raise IntrinsicsError(f"cannot derive K from EXIF: missing {missing}; give --hfov-deg or a checkerboard")


def sensor_width_from_table(make: str | None, model: str | None) -> float | None:
    """Sensor width (mm) from :data:`SENSOR_WIDTH_MM` by EXIF model, also trying "make model"."""
    if not model:
        return None
    keys = {k.lower(): v for k, v in SENSOR_WIDTH_MM.items()}
    for cand in (model, f"{make or ''} {model}"):
        v = keys.get(" ".join(cand.lower().split()))
        if v:
            return v
    return None


def crop_intrinsics(K: np.ndarray, x0: float, y0: float) -> np.ndarray:
    """K after cropping at column ``x0``, row ``y0``: ``c' = c − offset``."""
    K2 = np.array(K, dtype=np.float64, copy=True)
    K2[0, 2] -= x0
    K2[1, 2] -= y0
    return K2


def center_crop_box(width: int, height: int, aspect: float) -> tuple[int, int, int, int]:
    """The largest centred integer box of ``aspect`` = w/h inside ``width × height``: (x0, y0, w, h)."""
    if width / height > aspect:
        h = height
        w = min(width, int(round(height * aspect)))
    else:
        w = width
        h = min(height, int(round(width / aspect)))
    return (width - w) // 2, (height - h) // 2, w, h


def resize_crop(
    image: np.ndarray | None,
    K: np.ndarray,
    size: tuple[int, int] = MODEL_INPUT_SIZE,
    image_size: tuple[int, int] | None = None,
) -> tuple[np.ndarray | None, np.ndarray, tuple[int, int, int, int]]:
    """Centre-crop to the aspect of ``size`` then resize to ``size`` (cv2.INTER_AREA), updating K.

    Parameters
    ----------
    image : (H, W, ...) array or ``None`` (then only K is transformed; give ``image_size``).
    K : 3x3 intrinsics of ``image``.
    size : output (width, height), default the model's 320×240.

    Returns ``(image', K', crop_box)``; a 3D point projects to the same scene content before and
    after (the crop subtracts the offset; the resize scales about pixel edges, conventions §1).
    """
    if image is not None:
        h, w = image.shape[:2]
    elif image_size is not None:
        w, h = image_size
    else:
        raise InputError("resize_crop needs the image or its size")
    ow, oh = size
    x0, y0, cw, ch = center_crop_box(w, h, ow / oh)
    K2 = scale_intrinsics(crop_intrinsics(K, x0, y0), ow / cw, oh / ch)
    out = None
    if image is not None:
        crop = image[y0 : y0 + ch, x0 : x0 + cw]
        interp = cv2.INTER_AREA if cw >= ow else cv2.INTER_LINEAR
        out = cv2.resize(np.ascontiguousarray(crop), (ow, oh), interpolation=interp)
    return out, K2, (x0, y0, cw, ch)


def calibrate_checkerboard(
    views: Sequence[BoardView],
    pattern: tuple[int, int],
    square: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Pinhole calibration (``cv2.calibrateCamera``, k1 k2 p1 p2 k3) from detected board views.

    Returns ``(K, dist (5,), residuals)``; residuals hold the RMS reprojection error (px), the
    per-view RMS and the rejected views with their reasons.
    """
    good = [v for v in views if v.ok]
    rejected = {v.name: v.reason for v in views if not v.ok}
    if len(good) < 3:
        raise IntrinsicsError(
            f"checkerboard calibration needs >= 3 usable views, got {len(good)}; rejected: "
            + "; ".join(f"{k}: {r}" for k, r in rejected.items())
        )
    objs = [v.points(pattern, square).astype(np.float32).reshape(-1, 1, 3) for v in good]
    imgs = [cast(np.ndarray, v.corners).astype(np.float32).reshape(-1, 1, 2) for v in good]
    w, h = good[0].size
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(objs, imgs, (w, h), None, None)
    per_view = {}
    for v, obj, rv, tv in zip(good, objs, rvecs, tvecs):
        proj, _ = cv2.projectPoints(obj, rv, tv, K, dist)
        err = proj.reshape(-1, 2) - cast(np.ndarray, v.corners)
        per_view[v.name] = float(np.sqrt(np.mean(np.sum(err**2, 1))))
    residuals = {"rms_px": float(rms), "per_view_rms_px": per_view, "rejected_views": rejected, "views_used": len(good)}
    return K, dist.ravel(), residuals


def _profile(K, size, source, inputs, residuals, dist=(), model=None, **params) -> CameraProfile:
    w, h = size
    _, K2, box = resize_crop(None, K, MODEL_INPUT_SIZE, image_size=(w, h))
    hfov = 2 * math.degrees(math.atan2(w / 2.0, K[0, 0]))
    vfov = 2 * math.degrees(math.atan2(h / 2.0, K[1, 1]))
    return CameraProfile(
        provenance=make_provenance(inputs, tool="solidkit.calibration.camera", source=source, **params),
        residuals=residuals,
        source=source,
        image_size=(w, h),
        K=np.asarray(K).tolist(),
        dist=[float(x) for x in dist],
        model_input_K=K2.tolist(),
        crop_box=box,
        hfov_deg=hfov,
        vfov_deg=vfov,
        camera_model=model,
    )


_EXIF_USED = {
    "make",
    "model",
    "width",
    "height",
    "exposure_time",
    "f_number",
    "iso",
    "focal_length_mm",
    "focal_length_35mm",
    "focal_plane_px_per_mm",
    "exif_width",
    "exif_height",
}


def _size_only(photo: Path) -> CaptureMetadata:
    """Metadata with only the image size, for a non-JPEG/TIFF photo whose K comes from a FOV."""
    img = imread(photo)
    return CaptureMetadata(
        path=str(photo), width=img.shape[1], height=img.shape[0], warnings=["no_exif: not a JPEG or TIFF/DNG file"]
    )


def calibrate_camera_from_photo(
    photo: str | os.PathLike,
    sensor_width_mm: float | None = None,
    fov_deg: float | None = None,
) -> CameraProfile:
    """Camera profile of one photo from its EXIF (or a given horizontal FOV in degrees)."""
    photo = Path(photo)
    try:
        info = read_metadata(photo)
    except InputError:
        if fov_deg is None or not photo.is_file():
            raise
        info = _size_only(photo)  # e.g. a PNG perspective crop: no EXIF, K from the given FOV
    if fov_deg is None and info.width == 2 * info.height and "THETA" in (info.model or "").upper():
        raise IntrinsicsError(
            f"{photo}: a {info.model} equirectangular panorama has no pinhole K; for a perspective crop of it give "
            "--hfov-deg"
        )
    if fov_deg is not None:
        K, source = intrinsics_from_fov(math.radians(fov_deg), info.width, info.height), "fov"
    else:
        K, source = intrinsics_from_exif(info, sensor_width_mm)
    exif_used = {k: v for k, v in info.model_dump(include=_EXIF_USED).items() if v is not None}
    return _profile(
        K,
        (info.width, info.height),
        source,
        [photo],
        {"exif": exif_used},
        model=info.model,
        sensor_width_mm=sensor_width_mm,
        fov_deg=fov_deg,
    )


def calibrate_camera_from_board(
    images: Sequence[str | os.PathLike],
    pattern,
    square: float = 1.0,
    max_blur_px: float = 4.0,
) -> CameraProfile:
    """Camera profile from checkerboard (``pattern = (cols, rows)`` inner corners) or ChArUco
    (a :class:`~solidkit.calibration.boards.CharucoTarget`) views (``cv2.calibrateCamera``)."""
    views = detect_views(images, pattern, max_blur_px)
    grid = pattern if isinstance(pattern, tuple) else pattern.pattern
    K, dist, res = calibrate_checkerboard(views, grid, square)
    kind = "checkerboard" if isinstance(pattern, tuple) else "charuco"
    return _profile(K, views[0].size, kind, list(images), res, dist=dist, pattern=list(grid), square=square)
