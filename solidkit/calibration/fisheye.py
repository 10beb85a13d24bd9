"""Fisheye lens intrinsics from checkerboard views: Kannala-Brandt and Mei (unified) models.

Two OpenCV models are fitted to the same detected corners and the one with the smaller
*held-out* reprojection error (leave-k-views-out: fit on the rest, then fit only the held-out
view's pose with the intrinsics fixed) is chosen:

- ``kb``: Kannala & Brandt 2006, ``cv2.fisheye`` — ``r = f·θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸)``.
- ``mei``: Mei & Rives 2007 unified model, ``cv2.omnidir`` — projection on the unit sphere,
  then a pinhole shifted by ``xi`` with radial-tangential distortion (k1, k2, p1, p2).

The result is exported into the shared lens-profile format (:mod:`solidkit.camera.lens`,
``r(θ)`` as an odd polynomial): a KB fit maps exactly to ``poly = [f, f k1, f k2, f k3, f k4]``
(with ``f = (fx + fy)/2``; the aspect ``fy/fx`` is reported), a Mei fit is tabulated along 16
azimuths and fitted with :meth:`LensModel.from_table`.

OpenCV traps handled here: ``cv2.omnidir`` wants float64 points shaped ``(N, 1, 3)`` /
``(N, 1, 2)`` and silently drops views its initialisation cannot use (their indices come back
in ``idx``); when it drops every view it asserts, and ``cv2.fisheye`` with ``CALIB_CHECK_COND``
throws on an ill-conditioned view: both become a :class:`FisheyeCalibrationError` naming
the views and the reason, and ill-conditioned views are removed and the fit retried.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal, cast

import cv2
import numpy as np
from pydantic import Field
from scipy.optimize import least_squares

from solidkit.calibration.boards import BoardView
from solidkit.calibration.profile import Profile, make_provenance
from solidkit.camera.lens import LensModel, LensProfile
from solidkit.envmap.coords import rotation_from_rotvec
from solidkit.errors import SolidkitError

__all__ = [
    "FisheyeCalibrationError",
    "FisheyeFit",
    "FisheyeProfile",
    "fit_kb",
    "fit_mei",
    "fit_model",
    "held_out_error",
    "calibrate_fisheye",
    "reject_near_duplicates",
    "lens_model_from_fit",
    "lens_profile_from_calibrations",
]

ModelName = Literal["kb", "mei"]
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-10)
_MIN_VIEWS = 3


def _cv_message(exc: Exception) -> str:
    """The informative tail of an OpenCV error ("Assertion failed) ..." or the last line)."""
    text = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
    return text.split("error: ", 1)[-1][:160]


class FisheyeCalibrationError(SolidkitError):
    """Too few usable views, or OpenCV rejected all of them (the message says which and why)."""


@dataclass
class FisheyeFit:
    """One fitted fisheye model with its per-view residuals."""

    model: str
    size: tuple[int, int]
    K: np.ndarray
    D: np.ndarray
    xi: float | None
    rms_px: float
    per_view_rms_px: dict[str, float]
    rejected: dict[str, str]
    rvecs: list[np.ndarray] = field(default_factory=list)
    tvecs: list[np.ndarray] = field(default_factory=list)
    used: list[BoardView] = field(default_factory=list)  # the views of rvecs/tvecs, in order

    # -- the model as functions -------------------------------------------------------------
    def project(self, obj: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
        """Project (N, 3) points with pose (rvec, tvec) into pixels (N, 2)."""
        o = np.ascontiguousarray(obj, dtype=np.float64).reshape(-1, 1, 3)
        rv = np.asarray(rvec, np.float64).reshape(3, 1)
        tv = np.asarray(tvec, np.float64).reshape(3, 1)
        if self.model == "kb":
            p, _ = cv2.fisheye.projectPoints(o, rv, tv, self.K, self.D)
        else:
            p, _ = cv2.omnidir.projectPoints(o, rv, tv, self.K, float(cast(float, self.xi)), self.D)
        return p.reshape(-1, 2)

    def project_directions(self, d: np.ndarray) -> np.ndarray:
        """Project camera-frame directions (N, 3) into pixels (N, 2)."""
        return self.project(np.asarray(d, np.float64), np.zeros(3), np.zeros(3))

    def normalise(self, px: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) -> perspective-normalised coordinates (N, 2) (valid in front, θ < 90°)."""
        p = np.ascontiguousarray(px, dtype=np.float64).reshape(-1, 1, 2)
        if self.model == "kb":
            u = cv2.fisheye.undistortPoints(p, self.K, self.D)
            return u.reshape(-1, 2)
        u = cv2.omnidir.undistortPoints(p, self.K, self.D, np.array([[float(cast(float, self.xi))]]), np.eye(3))
        return u.reshape(-1, 2)

    def radius(self, theta: np.ndarray, azimuths: int = 16) -> np.ndarray:
        """Image height (px from the principal point) at incidence angles ``theta`` (rad), azimuth-mean."""
        theta = np.asarray(theta, np.float64)
        psi = (np.arange(azimuths) + 0.5) * 2 * np.pi / azimuths
        T, P = np.meshgrid(theta, psi, indexing="ij")
        d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
        px = self.project_directions(d)
        r = np.hypot(px[:, 0] - self.K[0, 2], px[:, 1] - self.K[1, 2]).reshape(T.shape)
        return r.mean(1)

    def summary(self) -> dict[str, Any]:
        out = {
            "model": self.model,
            "fx": float(self.K[0, 0]),
            "fy": float(self.K[1, 1]),
            "skew": float(self.K[0, 1]),
            "cx": float(self.K[0, 2]),
            "cy": float(self.K[1, 2]),
            "D": [float(x) for x in np.ravel(self.D)],
            "rms_px": self.rms_px,
            "per_view_rms_px": self.per_view_rms_px,
            "rejected_views": self.rejected,
        }
        if self.xi is not None:
            out["xi"] = float(self.xi)
        return out


def _usable(views: Sequence[BoardView]) -> tuple[list[BoardView], dict[str, str]]:
    good = [v for v in views if v.ok]
    rejected = {v.name: v.reason or "no corners" for v in views if not v.ok}
    return good, rejected


def _need(good: list[BoardView], rejected: dict[str, str], what: str) -> None:
    if len(good) < _MIN_VIEWS:
        detail = "; ".join(f"{k}: {r}" for k, r in rejected.items()) or "none rejected"
        raise FisheyeCalibrationError(
            f"{what} needs >= {_MIN_VIEWS} usable board views, got {len(good)} (rejected: {detail})"
        )


def _per_view(fit: FisheyeFit, used: list[BoardView], pattern, square) -> None:
    fit.used = list(used)
    for v, rv, tv in zip(used, fit.rvecs, fit.tvecs):
        e = fit.project(v.points(pattern, square), rv, tv) - v.corners
        fit.per_view_rms_px[v.name] = float(np.sqrt(np.mean(np.sum(e**2, 1))))


def fit_kb(views: Sequence[BoardView], pattern: tuple[int, int], square: float = 1.0) -> FisheyeFit:
    """Kannala-Brandt fit (``cv2.fisheye.calibrate``, skew fixed at 0, extrinsics recomputed).

    A view that makes the extrinsic problem ill-conditioned (``CALIB_CHECK_COND``) is removed
    with that reason and the fit is retried.
    """
    good, rejected = _usable(views)
    base = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW

    def run(views_, flags):
        O = [v.points(pattern, square).reshape(1, -1, 3).copy() for v in views_]
        I = [v.corners.reshape(1, -1, 2).astype(np.float64) for v in views_]
        return cv2.fisheye.calibrate(O, I, views_[0].size, None, None, flags=flags, criteria=_CRITERIA)

    while True:
        _need(good, rejected, "the Kannala-Brandt fit")
        try:
            rms, K, D, rvecs, tvecs = run(good, base | cv2.CALIB_CHECK_COND)
            break
        except cv2.error as exc:
            first_error = exc
            # OpenCV names the ill-conditioned view only in its message ("input array N"): no code to read
            m = re.search(r"input array (\d+)", str(exc))
        # A bad view elsewhere can make a good one look ill-conditioned: fit without the check and
        # let fit_model's outlier rounds prune by reprojection error; drop the flagged view only
        # when that fails too.
        try:
            rms, K, D, rvecs, tvecs = run(good, base)
            if np.isfinite(rms):
                break
        except cv2.error:
            pass
        if not m:
            raise FisheyeCalibrationError(f"cv2.fisheye.calibrate failed: {_cv_message(first_error)}") from None
        bad = good.pop(int(m.group(1)))
        rejected[bad.name] = "ill-conditioned board pose (cv2.fisheye CALIB_CHECK_COND)"
    fit = FisheyeFit("kb", good[0].size, K, D.reshape(-1), None, float(rms), {}, rejected, list(rvecs), list(tvecs))
    _per_view(fit, good, pattern, square)
    return fit


def fit_mei(views: Sequence[BoardView], pattern: tuple[int, int], square: float = 1.0) -> FisheyeFit:
    """Mei unified-model fit (``cv2.omnidir.calibrate``, skew fixed at 0).

    Views dropped by OpenCV's initialisation are listed with that reason; when it drops all of
    them, :class:`FisheyeCalibrationError` names every view instead of OpenCV's assertion.
    """
    good, rejected = _usable(views)
    _need(good, rejected, "the Mei (omnidir) fit")
    O = [v.points(pattern, square).reshape(-1, 1, 3).astype(np.float64) for v in good]  # trap: float64, (N, 1, 3)
    I = [cast(np.ndarray, v.corners).reshape(-1, 1, 2).astype(np.float64) for v in good]
    why = "rejected by cv2.omnidir's initialisation (no consistent initial focal length/pose from the board's lines)"
    try:
        rms, K, xi, D, rvecs, tvecs, idx = cv2.omnidir.calibrate(  # type: ignore[call-overload]  # stub: no None K
            O, I, good[0].size, None, None, None, cv2.omnidir.CALIB_FIX_SKEW, _CRITERIA
        )
    except cv2.error as exc:
        names = ", ".join(v.name for v in good)
        raise FisheyeCalibrationError(
            f"cv2.omnidir rejected every view ({names}): {why}; OpenCV said: {_cv_message(exc)}"
        ) from None
    idx = [] if idx is None else [int(i) for i in np.ravel(idx)]
    if len(idx) == 0:
        raise FisheyeCalibrationError(f"cv2.omnidir rejected every view ({', '.join(v.name for v in good)}): {why}")
    used = [good[i] for i in idx]
    for i, v in enumerate(good):
        if i not in idx:
            rejected[v.name] = why
    if not np.isfinite(rms) or len(used) < _MIN_VIEWS:
        raise FisheyeCalibrationError(
            f"the Mei (omnidir) fit kept {len(used)} views (rejected: "
            + "; ".join(f"{k}: {r}" for k, r in rejected.items())
            + ")"
        )
    fit = FisheyeFit(
        "mei",
        good[0].size,
        K,
        D.reshape(-1),
        float(np.ravel(xi)[0]),
        float(rms),
        {},
        rejected,
        [np.asarray(r) for r in rvecs],
        [np.asarray(t) for t in tvecs],
    )
    _per_view(fit, used, pattern, square)
    return fit


#: Two views whose board corners lie within this mean distance (px, or this fraction of the board's extent in the
#: image, whichever is larger) show the board in the same pose: the later one is a near-duplicate.
NEAR_DUPLICATE_PX = 1.0
NEAR_DUPLICATE_FRAC = 0.01


def reject_near_duplicates(views: Sequence[BoardView]) -> list[BoardView]:
    """``views`` with every usable view that repeats an earlier one's board pose marked rejected.

    The same pose is the same corners in the image (one lens, fixed intrinsics): a mean corner
    distance below ``max(NEAR_DUPLICATE_PX, NEAR_DUPLICATE_FRAC x the board's extent)`` (a
    second shot from a tripod, a re-saved file). Such a view adds no constraint on the lens,
    but would count twice in the fit and in the held-out folds.
    """
    out: list[BoardView] = []
    kept: list[BoardView] = []
    for v in views:
        if v.ok:
            c = np.asarray(v.corners, np.float64)
            extent = float(np.hypot(*np.ptp(c, axis=0)))
            limit = max(NEAR_DUPLICATE_PX, NEAR_DUPLICATE_FRAC * extent)
            for u in kept:
                cu = np.asarray(u.corners, np.float64)
                if cu.shape == c.shape and (
                    v.object_points is None or np.array_equal(np.asarray(u.object_points), np.asarray(v.object_points))
                ):
                    dist = float(np.mean(np.hypot(*(cu - c).T)))
                    if dist < limit:
                        v = replace(
                            v,
                            reason=f"duplicate: the board pose of {u.name} (corners {dist:.2f} px apart on average, "
                            f"< {limit:.2f} px)",
                        )
                        break
            if v.ok:
                kept.append(v)
        out.append(v)
    return out


def _fit_once(model: ModelName, views: Sequence[BoardView], pattern: tuple[int, int], square: float) -> FisheyeFit:
    if model == "kb":
        return fit_kb(views, pattern, square)
    if model == "mei":
        return fit_mei(views, pattern, square)
    raise FisheyeCalibrationError(f"unknown fisheye model {model!r} (kb or mei)")


def _best_without_one(
    model: ModelName, views: list[BoardView], pattern: tuple[int, int], square: float
) -> tuple[FisheyeFit, BoardView] | None:
    """The lowest-RMS fit among those leaving one view out, and that view (None when every fit fails)."""
    trials = []
    for v in views:
        try:
            trials.append((_fit_once(model, [u for u in views if u is not v], pattern, square), v))
        except FisheyeCalibrationError:
            continue
    return min(trials, key=lambda fv: fv[0].rms_px) if trials else None


def _fit_or_drop_one(model, views, pattern, square, outliers: dict[str, str]) -> FisheyeFit:
    """Fit; if OpenCV fails on the whole set, find the one view without which it succeeds."""
    try:
        return _fit_once(model, views, pattern, square)
    except FisheyeCalibrationError as exc:
        good = [v for v in views if v.ok]
        if len(good) <= _MIN_VIEWS:
            raise
        best = _best_without_one(model, good, pattern, square)
        if best is None:
            raise exc from None
        fit, culprit = best
        outliers[culprit.name] = f"the {model} fit fails with this view ({exc}) and succeeds without it"
        return fit


def fit_model(
    model: ModelName,
    views: Sequence[BoardView],
    pattern: tuple[int, int],
    square: float = 1.0,
    outlier_factor: float = 3.0,
    outlier_floor_px: float = 1.0,
    max_rounds: int = 3,
) -> FisheyeFit:
    """Fit ``model`` ("kb" or "mei"), rejecting outlier views and refitting.

    A view whose RMS reprojection error exceeds ``max(outlier_factor × median, outlier_floor_px)``
    (a mis-detected corner, a bent board) is rejected with its RMS as the reason, then the model
    is refitted (at most ``max_rounds`` times).
    """
    views = list(views)
    outliers: dict[str, str] = {}
    for _ in range(max_rounds):
        fit = _fit_or_drop_one(model, views, pattern, square, outliers)
        views = [v for v in views if v.name not in outliers]
        per = fit.per_view_rms_px
        limit = max(outlier_factor * float(np.median(list(per.values()))), outlier_floor_px)
        bad = {n for n, e in per.items() if e > limit}
        if not bad or len(per) - len(bad) < _MIN_VIEWS:
            break
        for v in views:
            if v.name in bad:
                outliers[v.name] = f"reprojection outlier: RMS {per[v.name]:.2f} px > {limit:.2f} px"
        views = [v for v in views if v.name not in bad]
    # A fit wrecked as a whole (every view bad, so no view stands out): drop, one at a time, the
    # view whose removal lowers the RMS most, while the RMS stays above the floor.
    for _ in range(max_rounds):
        kept = [v for v in views if v.name in fit.per_view_rms_px]
        if fit.rms_px <= outlier_floor_px or len(kept) <= _MIN_VIEWS:
            break
        found = _best_without_one(model, kept, pattern, square)
        if found is None:
            break
        best, worst = found
        if best.rms_px >= 0.8 * fit.rms_px:
            break
        outliers[worst.name] = f"removing it lowers the fit RMS from {fit.rms_px:.2f} to {best.rms_px:.2f} px"
        views = [u for u in kept if u is not worst]
        fit = best
    fit.rejected.update(outliers)
    return fit


def fit_pose(fit: FisheyeFit, obj: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Board pose in one view with the intrinsics fixed; returns ``(rvec, tvec, rms_px)``.

    Initialised by a planar PnP on the perspective-normalised corners, then refined by
    Levenberg-Marquardt on the model's reprojection error.
    """
    norm = fit.normalise(corners)
    good = np.all(np.isfinite(norm), axis=1) & (np.abs(norm).max(axis=1) < 50)  # drop points near/behind 90°
    if good.sum() < 4:
        raise FisheyeCalibrationError("a held-out view has fewer than 4 corners in front of the lens")
    o, n = np.ascontiguousarray(obj[good], dtype=np.float64), np.ascontiguousarray(norm[good])
    try:
        ok, rv, tv = cv2.solvePnP(o, n, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
    except cv2.error:
        ok = False
    if not ok:
        ok, rv, tv = cv2.solvePnP(o, n, np.eye(3), None)

    def resid(p):
        return (fit.project(obj, p[:3], p[3:]) - corners).ravel()

    sol = least_squares(resid, np.concatenate([np.ravel(rv), np.ravel(tv)]), method="lm")
    e = sol.fun.reshape(-1, 2)
    return sol.x[:3], sol.x[3:], float(np.sqrt(np.mean(np.sum(e**2, 1))))


def held_out_error(
    model: ModelName,
    views: Sequence[BoardView],
    pattern: tuple[int, int],
    square: float = 1.0,
    k: int | None = None,
) -> dict[str, Any]:
    """Leave-``k``-views-out reprojection error (px): each fold fits on the other views, then the
    held-out views' poses only. ``k`` defaults to ``ceil(n/5)`` (five folds)."""
    good, _ = _usable(views)
    n = len(good)
    if n < _MIN_VIEWS + 1:
        return {"k": 0, "rms_px": None, "per_view_rms_px": {}, "note": "too few views to hold any out"}
    k = k or max(1, math.ceil(n / 5))
    k = min(k, n - _MIN_VIEWS)
    per: dict[str, float] = {}
    failed: dict[str, str] = {}
    for start in range(0, n, k):
        held = good[start : start + k]
        train = good[:start] + good[start + k :]
        try:
            fit = fit_model(model, train, pattern, square)
        except FisheyeCalibrationError as exc:
            for v in held:
                failed[v.name] = f"fold fit failed: {exc}"
            continue
        for v in held:
            try:
                per[v.name] = fit_pose(fit, v.points(pattern, square), cast(np.ndarray, v.corners))[2]
            except (FisheyeCalibrationError, cv2.error) as exc:
                failed[v.name] = f"pose fit failed: {exc}"
    vals = np.array(list(per.values()))
    return {
        "k": k,
        "folds": math.ceil(n / k),
        "rms_px": float(np.sqrt(np.mean(vals**2))) if vals.size else None,
        "per_view_rms_px": per,
        "failed": failed,
    }


def _observed_max_angle(fit: FisheyeFit, views: Sequence[BoardView], pattern, square) -> float:
    """Largest incidence angle (deg) of any board corner under the fitted poses."""
    best = 0.0
    for v, rv, tv in zip(fit.used, fit.rvecs, fit.tvecs):
        R = rotation_from_rotvec(np.asarray(rv, np.float64).ravel())
        X = v.points(pattern, square) @ R.T + np.ravel(tv)
        th = np.degrees(np.arccos(np.clip(X[:, 2] / np.linalg.norm(X, axis=1), -1, 1)))
        best = max(best, float(th.max()))
    return best


def _max_angle_deg(fit: FisheyeFit, limit_deg: float | None) -> float:
    """The largest angle the exported model covers: the image's farthest corner, where ``r(θ)``
    stops increasing, or ``limit_deg``, whichever is smallest."""
    w, h = fit.size
    cx, cy = fit.K[0, 2], fit.K[1, 2]
    far = max(math.hypot(x - cx, y - cy) for x in (-0.5, w - 0.5) for y in (-0.5, h - 0.5))
    top = 180.0 if fit.model == "kb" else math.degrees(math.acos(-min(float(cast(float, fit.xi)), 1.0))) - 1.0
    th = np.radians(np.arange(0.0, min(top, limit_deg or 180.0) + 1e-9, 0.25))
    r = fit.radius(th)
    ok = np.nonzero(np.diff(r) <= 0)[0]
    n = len(th) if len(ok) == 0 else int(ok[0]) + 1
    reach = np.nonzero(r[:n] >= far)[0]
    if len(reach):
        n = min(n, int(reach[0]) + 1)
    return float(np.degrees(th[n - 1]))


def lens_model_from_fit(
    fit: FisheyeFit,
    name: str = "front",
    offset: tuple[float, float] = (0.0, 0.0),
    ypr_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
    max_angle_deg: float | None = None,
):
    """Export a fit as a :class:`solidkit.camera.lens.LensModel` (centre shifted by ``offset``,
    e.g. the crop origin of this lens' half in a dual-fisheye frame)."""
    cx, cy = float(fit.K[0, 2]) + offset[0], float(fit.K[1, 2]) + offset[1]
    top = _max_angle_deg(fit, max_angle_deg)
    if fit.model == "kb":
        f = 0.5 * (float(fit.K[0, 0]) + float(fit.K[1, 1]))
        poly = [f] + [f * float(k) for k in np.ravel(fit.D)[:4]]
        return LensModel(name=name, center=(cx, cy), poly=poly, max_angle_deg=top, ypr_deg=tuple(ypr_deg))
    th = np.arange(0.0, top + 1e-9, 0.5)
    r = fit.radius(np.radians(th))
    return LensModel.from_table(
        name, (cx, cy), th, r, ypr_deg=cast("tuple[float, float, float]", tuple(ypr_deg)), max_angle_deg=top, degree=11
    )


class FisheyeProfile(Profile):
    """One fisheye lens calibrated from board views: both models, the choice and its export."""

    KIND = "fisheye"
    lens_name: str
    image_size: tuple[int, int]
    offset: tuple[float, float] = (0.0, 0.0)
    pattern: tuple[int, int]
    square: float
    chosen_model: str
    choice_reason: str
    models: dict[str, dict] = Field(default_factory=dict, description="per model: parameters, residuals, held-out")
    lens: dict = Field(description="the chosen model as a camera.lens LensModel (lens-profile format)")
    observed_max_angle_deg: float
    views: dict[str, str] = Field(default_factory=dict, description="view -> 'used' or the rejection reason")
    warnings: list[str] = Field(
        default_factory=list, description="what the calibration cannot vouch for: a field beyond the boards, a choice"
    )

    def lens_model(self):
        return LensModel.model_validate(self.lens)


#: The model choice needs held-out errors of at least this many views in both models ...
MIN_CHOICE_VIEWS = 6
#: ... and a mean paired difference of at least this many standard errors.
CHOICE_SIGMAS = 2.0


def _choose(fits: dict[str, FisheyeFit], info: dict[str, dict]) -> tuple[str, str, bool]:
    """The model with the lower held-out RMS, why, and whether the views can tell the models apart.

    Reliable: one model only (nothing to choose), or each view's held-out error under both models
    for at least :data:`MIN_CHOICE_VIEWS` views with a mean difference beyond
    :data:`CHOICE_SIGMAS` standard errors (a paired comparison: the views' own difficulty cancels).
    """

    def score(m: str) -> float:
        v = info[m]["held_out"]["rms_px"]
        return v if v is not None else fits[m].rms_px

    chosen = min(fits, key=score)
    if len(fits) == 1:
        return chosen, f"the only model fitted ({chosen})", True
    if not all(info[m]["held_out"]["rms_px"] is not None for m in fits):
        return chosen, "lowest fit RMS (too few views to hold out: the choice is not tested on unseen views)", False
    reason = "lowest held-out RMS: " + ", ".join(f"{m} {score(m):.4g} px" for m in fits)
    other = min((m for m in fits if m != chosen), key=score)
    a, b = info[chosen]["held_out"]["per_view_rms_px"], info[other]["held_out"]["per_view_rms_px"]
    common = sorted(set(a) & set(b))
    d = np.array([b[k] - a[k] for k in common])
    if len(d) < MIN_CHOICE_VIEWS:
        return chosen, f"{reason}; too few views ({len(d)} held out in both, < {MIN_CHOICE_VIEWS}) to tell", False
    se = float(np.std(d, ddof=1) / math.sqrt(len(d)))
    if float(d.mean()) < CHOICE_SIGMAS * se:
        return (
            chosen,
            f"{reason}; the views do not tell the models apart ({other} worse by {d.mean():.3g} ± {se:.2g} px over "
            f"{len(d)} views): either fits as well",
            False,
        )
    return chosen, f"{reason} ({other} worse by {d.mean():.3g} ± {se:.2g} px over {len(d)} views)", True


def calibrate_fisheye(
    views: Sequence[BoardView],
    pattern: tuple[int, int],
    square: float = 1.0,
    models: Sequence[ModelName] = ("kb", "mei"),
    holdout_k: int | None = None,
    lens_name: str = "front",
    offset: tuple[float, float] = (0.0, 0.0),
    ypr_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
    max_angle_deg: float | None = None,
    inputs: Sequence[Any] = (),
) -> FisheyeProfile:
    """Fit each model, measure its held-out error, choose the lower one, export it.

    Residuals: per model the RMS and per-view reprojection error (px) on the fitted views, and
    the leave-k-out held-out RMS and per-view errors (px). A model whose fit fails is reported
    with its error and skipped; if all fail the first error is raised.

    What the views cannot vouch for is refused or said (``warnings``): a view repeating an earlier
    one (same pixels, :func:`~solidkit.calibration.boards.detect_views`; same board pose,
    :func:`reject_near_duplicates`) is rejected; the lens is exported up to the largest incidence
    angle a board corner reached (``observed_max_angle_deg``) unless ``max_angle_deg`` asks for
    more (then ``extrapolated``); a choice of model the held-out errors do not support
    (:func:`_choose`) is ``model_choice_unreliable``.
    """
    views = reject_near_duplicates(views)
    fits: dict[str, FisheyeFit] = {}
    info: dict[str, dict] = {}
    errors: list[FisheyeCalibrationError] = []
    for m in models:
        try:
            fit = fit_model(m, views, pattern, square)
        except FisheyeCalibrationError as exc:
            info[m] = {"error": str(exc)}
            errors.append(exc)
            continue
        fits[m] = fit
        kept = [v for v in views if v.name in fit.per_view_rms_px]
        info[m] = fit.summary() | {"held_out": held_out_error(m, kept, pattern, square, holdout_k)}
    if not fits:
        raise errors[0]

    chosen, reason, reliable = _choose(fits, info)
    fit = fits[chosen]
    used_views = {v.name: (v.reason or "no corners") if not v.ok else "used" for v in views}
    for name, why in fit.rejected.items():
        used_views[name] = why
    obs = _observed_max_angle(fit, views, pattern, square)
    warnings: list[str] = []
    if not reliable:
        warnings.append(f"model_choice_unreliable: {reason}")
    # the model is known where the boards were: by default it is exported up to there, and no farther
    reach = _max_angle_deg(fit, None)
    lens = lens_model_from_fit(fit, lens_name, offset, ypr_deg, obs if max_angle_deg is None else max_angle_deg)
    if max_angle_deg is None and reach > obs + 0.5:
        warnings.append(
            f"field_limited_to_boards: the lens is exported up to {lens.max_angle_deg:.1f}° of incidence, the largest "
            f"angle a board corner reached (the {chosen} model would reach {reach:.1f}° at the image's edge, "
            "unmeasured); add views with the board near the image's edge, or give --max-angle-deg to extrapolate"
        )
    elif lens.max_angle_deg > obs + 0.5:
        warnings.append(
            f"extrapolated: the lens is exported up to {lens.max_angle_deg:.1f}° of incidence, but the boards covered "
            f"only {obs:.1f}°: r(theta) beyond is the {chosen} model's extrapolation, unmeasured"
        )
    # how faithfully the exported polynomial reproduces the fitted model over the observed angles
    th = np.radians(np.linspace(0, min(obs, lens.max_angle_deg), 200))
    export_err = float(np.abs(lens.radius(th) - fit.radius(th)).max())
    held = info[chosen]["held_out"]
    residuals = {
        "model": chosen,
        "rms_px": fit.rms_px,
        "held_out_rms_px": held["rms_px"],
        "per_view_rms_px": fit.per_view_rms_px,
        "held_out_per_view_rms_px": held["per_view_rms_px"],
        "aspect_fy_over_fx": float(fit.K[1, 1] / fit.K[0, 0]),
        "export_max_radius_error_px": export_err,
        "views_used": len(fit.per_view_rms_px),
        "views_rejected": {k: v for k, v in used_views.items() if v != "used"},
        "model_choice_reliable": reliable,
        "model_max_angle_deg": reach,
        "exported_max_angle_deg": lens.max_angle_deg,
    }
    prov = make_provenance(
        list(inputs),
        tool="solidkit.calibration.fisheye.calibrate_fisheye",
        models=list(models),
        holdout_k=holdout_k,
        pattern=list(pattern),
        square=square,
    )
    return FisheyeProfile(
        provenance=prov,
        residuals=residuals,
        lens_name=lens_name,
        image_size=tuple(fit.size),
        offset=tuple(offset),
        pattern=tuple(pattern),
        square=square,
        chosen_model=chosen,
        choice_reason=reason,
        models=info,
        lens=lens.model_dump(mode="json"),
        observed_max_angle_deg=obs,
        views=used_views,
        warnings=warnings,
    )


def lens_profile_from_calibrations(
    calibrations: Sequence[FisheyeProfile],
    name: str,
    reference_size: tuple[int, int],
    camera_models: Sequence[str] = (),
    base=None,
):
    """Assemble (or update) a :class:`solidkit.camera.lens.LensProfile` from calibrated lenses.

    ``base`` (an existing LensProfile) keeps its other lenses; a lens with the same name is replaced.
    """
    lenses = {l.name: l for l in (base.lenses if base is not None else [])}
    res = dict(base.residuals) if base is not None else {}
    for c in calibrations:
        lenses[c.lens_name] = c.lens_model()
        res[c.lens_name] = {
            k: c.residuals[k]
            for k in ("model", "rms_px", "held_out_rms_px", "views_used", "export_max_radius_error_px")
        }
        res[c.lens_name]["observed_max_angle_deg"] = c.observed_max_angle_deg
        if c.warnings:
            res[c.lens_name]["warnings"] = list(c.warnings)
    src = (
        "solidkit calibrate lens (checkerboard views; "
        + ", ".join(
            f"{c.lens_name}: {c.chosen_model}, held-out {c.residuals['held_out_rms_px']:.3g} px"
            if c.residuals["held_out_rms_px"] is not None
            else f"{c.lens_name}: {c.chosen_model}"
            for c in calibrations
        )
        + ")"
    )
    if base is not None and base.reference_size != tuple(reference_size):
        raise FisheyeCalibrationError(
            f"the existing profile is for {base.reference_size[0]}x{base.reference_size[1]} images; these views are "
            f"{reference_size[0]}x{reference_size[1]}"
        )
    return LensProfile(
        model=name,
        camera_models=list(camera_models) or (list(base.camera_models) if base is not None else []),
        source=src if base is None else f"{base.source}; {src}",
        reference_size=tuple(reference_size),
        lenses=list(lenses.values()),
        parent=base.parent if base is not None else None,
        residuals=res,
        notes="lens orientations (ypr_deg) are not measured by board calibration of each lens alone",
    )
