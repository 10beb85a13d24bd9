"""White balance and a 3x3 colour-correction matrix (CCM) from a 24-patch ColorChecker.

Everything happens in **linear** RGB: the camera's linear RGB (a raw decode, or an 8-bit image
linearised with a response profile) is mapped to linear sRGB (Rec.709 primaries, D65), the
radiometric space of solidkit (conventions §5):

    corrected = M · diag(wb) · camera,        M, wb fitted on the chart's 24 patches.

Reference values: colour-science's ``'ColorChecker24 - After November 2014'`` (xyY under D50),
converted to linear sRGB with a Bradford adaptation to D65. Errors are CIEDE2000 on CIE Lab
(D65 white), computed before (one exposure scalar only), after white balance, and after the CCM.

The chart is located with OpenCV's ``cv2.mcc`` detector (classical, no DNN; the chart type
must be set explicitly: in opencv-contrib 5.0 a fresh detector reports type 320, not MCC24)
or from four clicked points: the centres of the corner patches, in the order dark skin (1),
bluish green (6), black (24), white (19).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from pydantic import Field
from scipy.optimize import least_squares

from solidkit.calibration.profile import Profile, make_provenance
from solidkit.camera.raw import is_raw_file, read_raw
from solidkit.envmap.io import imread, read_exr, srgb_decode
from solidkit.envmap.resample import sample_image
from solidkit.envmap.sun import REC709_LUMINANCE
from solidkit.errors import InputError, SolidkitError

__all__ = [
    "CHART_NAME",
    "ColourProfile",
    "ChartError",
    "reference_linear_srgb",
    "detect_chart",
    "chart_homography_from_corners",
    "patch_centres",
    "sample_patches",
    "fit_white_balance",
    "fit_ccm",
    "refine_ccm_delta_e",
    "delta_e2000",
    "lab_from_linear_srgb",
    "apply_colour",
    "calibrate_colour",
    "read_linear_image",
]

CHART_NAME = "ColorChecker24 - After November 2014"
ROWS, COLS = 4, 6
NEUTRALS = slice(18, 24)  # white ... black
# Chart coordinates: patch (row r, column c) has its centre at (c, r) (units of patch pitch).
CORNER_PATCHES = (0, 5, 23, 18)  # dark skin, bluish green, black, white (clockwise)


class ChartError(SolidkitError):
    """The colour chart could not be found or sampled (give --corners), or patches are clipped."""


class ColourProfile(Profile):
    """White balance and CCM mapping camera linear RGB to linear sRGB (D65)."""

    KIND = "colour"
    white_balance: list[float] = Field(description="per-channel gains applied first (green = 1)")
    ccm: list[list[float]] = Field(description="3x3, applied after the white balance, rows = output R, G, B")
    exposure_gain: float = Field(description="scalar folded into ccm that maps the chart to reflectance scale")
    white_preserving: bool = True
    chart: str = CHART_NAME
    detection: str = Field(description="'mcc' or 'corners'")
    patch_centres_px: list[list[float]] = Field(default_factory=list)

    def matrix(self, preserve_exposure: bool = True) -> np.ndarray:
        """The full 3x3 ``M · diag(wb)``; divided by ``exposure_gain`` when ``preserve_exposure``."""
        m = np.asarray(self.ccm, dtype=np.float64) @ np.diag(self.white_balance)
        return m / self.exposure_gain if preserve_exposure else m


def reference_linear_srgb(name: str = CHART_NAME) -> np.ndarray:
    """The chart's 24 reference colours as linear sRGB (D65, Bradford), shape (24, 3), white ≈ 0.9."""
    import colour  # lazy: colour-science takes seconds to import; only colour calibration needs it

    cc = colour.CCS_COLOURCHECKERS[name]
    xyy = np.array(list(cc.data.values()), dtype=np.float64)
    xyz = colour.xyY_to_XYZ(xyy)
    return colour.XYZ_to_RGB(
        xyz, "sRGB", illuminant=cc.illuminant, chromatic_adaptation_transform="Bradford", apply_cctf_encoding=False
    )


@lru_cache(maxsize=1)
def _srgb_to_xyz_and_white() -> tuple[np.ndarray, np.ndarray]:
    import colour  # lazy: colour-science takes seconds to import; only colour calibration needs it

    M = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ, dtype=np.float64)
    xy = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    return M, np.asarray(colour.xyY_to_XYZ([xy[0], xy[1], 1.0]), dtype=np.float64)


def lab_from_linear_srgb(rgb: np.ndarray) -> np.ndarray:
    """CIE Lab (D65 white, L in 0..100) of linear sRGB colours (…, 3) (CIE 15 formulas)."""
    M, white = _srgb_to_xyz_and_white()
    t = (np.asarray(rgb, dtype=np.float64) @ M.T) / white
    d = 6.0 / 29.0
    f = np.where(t > d**3, np.cbrt(t), t / (3 * d * d) + 4.0 / 29.0)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], -1)


def delta_e2000(rgb_a: np.ndarray, rgb_b: np.ndarray) -> np.ndarray:
    """CIEDE2000 between linear-sRGB colours (…, 3), on CIE Lab with a D65 white (colour-science's
    ``delta_E(method='CIE 2000')``)."""
    import colour  # lazy: colour-science takes seconds to import; only colour calibration needs it

    return np.asarray(colour.delta_E(lab_from_linear_srgb(rgb_a), lab_from_linear_srgb(rgb_b), method="CIE 2000"))


def patch_centres(H: np.ndarray) -> np.ndarray:
    """Image positions (24, 2) of the patch centres under the chart->image homography ``H``."""
    rc = np.array([(c, r) for r in range(ROWS) for c in range(COLS)], dtype=np.float64)
    return cv2.perspectiveTransform(rc[None], H)[0]


def chart_homography_from_corners(corners: np.ndarray) -> np.ndarray:
    """Homography chart -> image from the 4 corner-patch centres (dark skin, bluish green, black, white)."""
    corners = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    if corners.shape != (4, 2):
        raise ChartError(f"--corners needs 4 points (8 numbers), got {corners.size} numbers")
    src = np.array([(0, 0), (COLS - 1, 0), (COLS - 1, ROWS - 1), (0, ROWS - 1)], dtype=np.float64)
    H, _ = cv2.findHomography(src, corners)
    if H is None:
        raise ChartError(f"the 4 corners {corners.tolist()} do not define a chart (degenerate)")
    return H


def detect_chart(image_bgr8: np.ndarray) -> np.ndarray | None:
    """Find a ColorChecker 24 with ``cv2.mcc``; returns the chart->image homography or ``None``.

    ``image_bgr8`` is an 8-bit BGR display image (e.g. the linear image tone-mapped).
    """
    if not hasattr(cv2, "mcc"):
        return None
    det = cv2.mcc.CCheckerDetector_create()  # type: ignore[attr-defined]  # in cv2.mcc, not in its stub
    det.setColorChartType(cv2.mcc.MCC24)
    det.setUseDnnModel(False)
    if not det.process(np.ascontiguousarray(image_bgr8), 1):
        return None
    quads = np.asarray(det.getBestColorChecker().getColorCharts(), dtype=np.float64)
    if quads.shape != (96, 2):
        return None
    centres = quads.reshape(24, 4, 2).mean(1)
    rc = np.array([(c, r) for r in range(ROWS) for c in range(COLS)], dtype=np.float64)
    H, _ = cv2.findHomography(rc, centres)
    return H


def _orient(H: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flip the chart by 180° when the neutral row runs black->white (white must be patch 19)."""
    y = samples @ np.asarray(REC709_LUMINANCE)
    if y[18] >= y[23]:
        return H, samples
    R = np.array([[-1, 0, COLS - 1], [0, -1, ROWS - 1], [0, 0, 1]], dtype=np.float64)
    return H @ R, samples[::-1].copy()


def sample_patches(image: np.ndarray, H: np.ndarray, radius: float = 0.25, n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """Mean linear RGB of each patch: an ``n``×``n`` grid within ±``radius`` pitch of its centre.

    Returns ``(means (24, 3), stds (24, 3))``. Bilinear sampling (:func:`solidkit.envmap.resample.sample_image`),
    pixel centres at integer coordinates (conventions §1).
    """
    off = np.linspace(-radius, radius, n)
    ox, oy = np.meshgrid(off, off)
    rc = np.array([(c, r) for r in range(ROWS) for c in range(COLS)], dtype=np.float64)
    pts = (rc[:, None, :] + np.stack([ox.ravel(), oy.ravel()], 1)[None]).reshape(1, -1, 2)
    xy = cv2.perspectiveTransform(pts, H)[0].astype(np.float32)
    h, w = image.shape[:2]
    if (xy[:, 0] < 0).any() or (xy[:, 1] < 0).any() or (xy[:, 0] > w - 1).any() or (xy[:, 1] > h - 1).any():
        raise ChartError("chart patches fall outside the image (check the corners)")
    vals = sample_image(np.asarray(image, dtype=np.float32), xy[:, 0], xy[:, 1])
    vals = vals.reshape(24, n * n, 3).astype(np.float64)
    return vals.mean(1), vals.std(1)


def fit_white_balance(camera: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-channel gains (green = 1) mapping the neutral patches' camera RGB to neutral.

    Least squares over the six neutral patches per channel, then normalised to the green gain.
    """
    cam, ref = camera[NEUTRALS], reference[NEUTRALS]
    g = (cam * ref).sum(0) / np.maximum((cam * cam).sum(0), 1e-30)
    return g / g[1]


def fit_ccm(
    camera: np.ndarray, reference: np.ndarray, white_preserving: bool = True, white_index: int = 18
) -> np.ndarray:
    """Least-squares 3x3 ``M`` with ``M · camera_i ≈ reference_i`` over the patches.

    With ``white_preserving`` the white patch is mapped exactly (``M · c_w = r_w``): each row is a
    linearly constrained least-squares problem solved through its KKT system.
    """
    A = np.asarray(camera, dtype=np.float64)
    B = np.asarray(reference, dtype=np.float64)
    if not white_preserving:
        M, *_ = np.linalg.lstsq(A, B, rcond=None)
        return M.T
    w, rw = A[white_index], B[white_index]
    K = np.zeros((4, 4))
    K[:3, :3] = 2 * A.T @ A
    K[:3, 3] = w
    K[3, :3] = w
    M = np.zeros((3, 3))
    for i in range(3):
        rhs = np.concatenate([2 * A.T @ B[:, i], [rw[i]]])
        M[i] = np.linalg.solve(K, rhs)[:3]
    return M


def refine_ccm_delta_e(
    M0: np.ndarray,
    camera: np.ndarray,
    reference: np.ndarray,
    white_preserving: bool = True,
    white_index: int = 18,
) -> np.ndarray:
    """Refine a CCM to minimise the patches' CIEDE2000 (sum of squares), starting from ``M0``.

    Linear least squares weighs bright patches most (their linear errors are largest), which can
    leave dark patches perceptually worse than no correction; this step optimises the reported
    metric directly. With ``white_preserving`` the updates stay in the null space of the white
    patch (``M · c_w`` is unchanged).
    """
    A = np.asarray(camera, dtype=np.float64)
    B = np.asarray(reference, dtype=np.float64)
    if white_preserving:
        w = A[white_index] / np.linalg.norm(A[white_index])
        N = np.linalg.svd(w[None, :])[2][1:].T  # (3, 2): orthonormal basis of w's complement
    else:
        N = np.eye(3)
    k = N.shape[1]

    def matrix(u):
        return M0 + u.reshape(3, k) @ N.T

    def resid(u):
        return delta_e2000(A @ matrix(u).T, B)

    sol = least_squares(resid, np.zeros(3 * k), method="lm" if A.shape[0] >= 3 * k else "trf")
    M = matrix(sol.x)
    return M if np.sum(resid(sol.x) ** 2) <= np.sum(resid(np.zeros(3 * k)) ** 2) else M0


def apply_colour(image: np.ndarray, profile: ColourProfile, preserve_exposure: bool = True) -> np.ndarray:
    """Apply a colour profile to a linear (…, 3) image; returns float32 linear sRGB."""
    m = profile.matrix(preserve_exposure).astype(np.float32)
    return np.asarray(image, dtype=np.float32) @ m.T


def _display8(linear: np.ndarray) -> np.ndarray:
    """An 8-bit BGR view of a linear RGB image for the detector (99th percentile -> ~white)."""
    scale = np.percentile(linear, 99) or 1.0
    disp = np.clip(linear / scale, 0, 1) ** (1 / 2.2)
    return np.ascontiguousarray((disp[..., ::-1] * 255 + 0.5).astype(np.uint8))


def read_linear_image(path: str | os.PathLike, response: np.ndarray | None = None) -> np.ndarray:
    """Camera linear RGB of an image file, float32 (H, W, 3), roughly in [0, 1].

    Raw files (.dng, .cr2, .nef, .arw, ...) are demosaiced in the camera's own raw colour space,
    without white balance or colour matrix (:func:`solidkit.camera.raw.read_raw` with
    ``wb="none", color="camera"``: black level subtracted, scaled by the white level). 8-bit images
    are linearised with ``response`` (a (256, 3) inverse response) when given, else sRGB-decoded.
    EXR files are read as they are.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if is_raw_file(path):
        return read_raw(path, wb="none", color="camera").linear
    if suffix == ".exr":
        img = read_exr(path)[0][..., :3]
        if not np.isfinite(img).all():
            raise InputError(f"{path}: {int((~np.isfinite(img)).any(-1).sum())} pixel(s) are NaN or Inf")
        return img
    img = imread(path, cv2.IMREAD_COLOR)
    rgb8 = img[..., ::-1]
    if response is not None:
        resp = np.asarray(response, dtype=np.float32)
        return np.stack([resp[rgb8[..., c], c] for c in range(3)], -1)
    return srgb_decode(rgb8.astype(np.float32) / 255.0).astype(np.float32)


def calibrate_colour(
    image: np.ndarray,
    corners: np.ndarray | None = None,
    white_preserving: bool = True,
    clip_level: float = 0.98,
    inputs: Sequence[str | os.PathLike] = (),
    objective: str = "delta-e",
) -> ColourProfile:
    """Fit white balance + CCM on a linear camera image of a ColorChecker 24.

    Parameters
    ----------
    image : (H, W, 3) float, camera linear RGB (clipped highlights near ``clip_level``).
    corners : optional (4, 2) corner-patch centres in pixels (see module doc); otherwise ``cv2.mcc``.
    white_preserving : constrain the CCM to map the white patch exactly.
    objective : "delta-e" (default): linear least squares, then refined to minimise CIEDE2000
        (:func:`refine_ccm_delta_e`); "linear": the least-squares fit only.

    Residuals: CIEDE2000 mean / max / per patch, before (exposure only), after white balance and
    after the CCM (colour-science, method 'CIE 2000').
    """
    if objective not in ("delta-e", "linear"):
        raise InputError(f"unknown CCM objective {objective!r} (delta-e or linear)")
    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 3 or image.shape[2] < 3:
        raise InputError(f"colour calibration needs an RGB image, got shape {image.shape}")
    image = image[..., :3]
    H: np.ndarray | None
    if corners is not None:
        H, how = chart_homography_from_corners(corners), "corners"
    else:
        H, how = detect_chart(_display8(image)), "mcc"
        if H is None:
            raise ChartError("no ColorChecker 24 found by cv2.mcc; give the corner-patch centres with --corners")
    cam, std = sample_patches(image, H)
    H, cam = _orient(H, cam)
    clipped = np.nonzero((cam.max(1) >= clip_level) | (cam.min(1) <= 0))[0]
    ref = reference_linear_srgb()
    use = np.setdiff1d(np.arange(24), clipped)
    if 18 in clipped or len(use) < 12:
        raise ChartError(f"patches {[int(i) + 1 for i in clipped]} are clipped or black; expose the chart lower")
    wb = fit_white_balance(cam, ref)
    cam_wb = cam * wb
    wi = int(np.nonzero(use == 18)[0][0])
    ccm_ls = fit_ccm(cam_wb[use], ref[use], white_preserving=white_preserving, white_index=wi)
    ccm = refine_ccm_delta_e(ccm_ls, cam_wb[use], ref[use], white_preserving, wi) if objective == "delta-e" else ccm_ls
    after = cam_wb @ ccm.T
    # "before": the camera values with one least-squares exposure scalar; "wb": plus a scalar too
    s0 = float((cam[use] * ref[use]).sum() / (cam[use] ** 2).sum())
    s1 = float((cam_wb[use] * ref[use]).sum() / (cam_wb[use] ** 2).sum())
    de = {
        k: delta_e2000(v, ref)
        for k, v in (
            ("before", cam * s0),
            ("white_balance", cam_wb * s1),
            ("ccm_linear_lsq", cam_wb @ ccm_ls.T),
            ("ccm", after),
        )
    }
    # generalisation: each patch predicted by a least-squares CCM fitted without it (white kept)
    loo = []
    for i in use:
        if i == 18:
            continue
        rest = use[use != i]
        M_i = fit_ccm(
            cam_wb[rest], ref[rest], white_preserving=white_preserving, white_index=int(np.nonzero(rest == 18)[0][0])
        )
        loo.append(float(delta_e2000(M_i @ cam_wb[i], ref[i])))
    grey = cam_wb[18]
    y = np.asarray(REC709_LUMINANCE)
    gain = float((ccm @ grey) @ y / (grey @ y))
    residuals = {
        "ciede2000_mean": {k: float(v[use].mean()) for k, v in de.items()},
        "ciede2000_max": {k: float(v[use].max()) for k, v in de.items()},
        "ciede2000_per_patch_after": [round(float(x), 4) for x in de["ccm"]],
        "ciede2000_leave_one_patch_out_mean": float(np.mean(loo)),
        "patches_used": [int(i) + 1 for i in use],
        "patches_clipped": [int(i) + 1 for i in clipped],
        "patch_noise_rel": float(np.median(std / np.maximum(cam, 1e-9))),
    }
    prov = make_provenance(
        list(inputs),
        tool="solidkit.calibration.colour.calibrate_colour",
        white_preserving=white_preserving,
        objective=objective,
        detection=how,
        corners=None if corners is None else np.asarray(corners).tolist(),
    )
    return ColourProfile(
        provenance=prov,
        residuals=residuals,
        white_balance=wb.tolist(),
        ccm=ccm.tolist(),
        exposure_gain=gain,
        white_preserving=white_preserving,
        detection=how,
        patch_centres_px=patch_centres(H).tolist(),
    )
