"""Robust two-view geometry on unit rays: a pure rotation, and a relative pose between level panoramas.

- :func:`estimate_rotation`: ``b ≈ R a`` for matched rays of two views taken from one place (the
  photo and the Theta shot at the photo camera's position). RANSAC on the two-ray minimal
  solution, then the least-squares rotation over the inliers (Wahba's problem,
  :meth:`scipy.spatial.transform.Rotation.align_vectors`).
- :func:`estimate_relative_pose`: rotation and translation direction between two panoramas
  taken at different places, with pycolmap's LO-RANSAC on camera rays (the equirectangular
  case: rays, not pinhole pixels), followed by :func:`pycolmap.refine_relative_pose`.

Angles are radians; rays are ``(N, 3)`` unit vectors in each view's frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from solidkit._imports import pycolmap as _pycolmap
from solidkit.envmap.coords import angular_distance, rotation_y
from solidkit.errors import InputError

__all__ = [
    "RotationFit",
    "PoseFit",
    "LevelPoseFit",
    "estimate_rotation",
    "estimate_relative_pose",
    "estimate_level_pose",
]


@dataclass(frozen=True)
class RotationFit:
    """Result of :func:`estimate_rotation`: ``R`` (3, 3) with ``b ≈ R a``, the inlier mask, and
    the RMS angular residual of the inliers (radians)."""

    R: np.ndarray
    inliers: np.ndarray
    rms: float

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def _triad(a1: np.ndarray, a2: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """Rotations ``(K, 3, 3)`` mapping the frame of (a1, a2) onto the frame of (b1, b2) (triad method)."""

    def frame(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        e1 = u / np.linalg.norm(u, axis=-1, keepdims=True)
        e2 = np.cross(u, v)
        e2 /= np.maximum(np.linalg.norm(e2, axis=-1, keepdims=True), 1e-12)
        return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)

    return frame(b1, b2) @ np.swapaxes(frame(a1, a2), -1, -2)


def estimate_rotation(
    a: np.ndarray,
    b: np.ndarray,
    *,
    threshold: float = math.radians(0.5),
    iterations: int = 2000,
    seed: int = 0,
    min_inliers: int = 8,
) -> RotationFit | None:
    """Robust ``R`` with ``b ≈ R a`` from matched unit rays; ``None`` with too few inliers.

    RANSAC: ``iterations`` random pairs (at least 2° apart), each giving a rotation by the triad
    method; the rotation with the most rays within ``threshold`` of their match wins; it is refit
    by least squares on its inliers twice (inliers re-selected each time).
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    n = len(a)
    if n < max(2, min_inliers):
        return None
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, iterations)
    j = rng.integers(0, n, iterations)
    ok = (i != j) & (np.sum(a[i] * a[j], axis=1) < math.cos(math.radians(2.0)))
    i, j = i[ok], j[ok]
    if not len(i):
        return None
    Rs = _triad(a[i], a[j], b[i], b[j])  # (K, 3, 3)
    best, best_count = None, -1
    cos_t = math.cos(threshold)
    for start in range(0, len(Rs), 256):  # chunks keep the (K, N, 3) product small
        pred = np.einsum("kij,nj->kni", Rs[start : start + 256], a)
        counts = (np.einsum("kni,ni->kn", pred, b) >= cos_t).sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best, best_count = Rs[start + k], int(counts[k])
    assert best is not None  # counts >= 0 > -1: the first chunk sets it
    R = best
    for _ in range(3):
        inl = angular_distance(a @ R.T, b) <= threshold
        if inl.sum() < min_inliers:
            return None
        rot, _ = Rotation.align_vectors(b[inl], a[inl])
        R = rot.as_matrix()
    inl = angular_distance(a @ R.T, b) <= threshold
    if inl.sum() < min_inliers:
        return None
    rms = float(np.sqrt(np.mean(angular_distance(a[inl] @ R.T, b[inl]) ** 2)))
    return RotationFit(R, inl, rms)


@dataclass(frozen=True)
class PoseFit:
    """Result of :func:`estimate_relative_pose`: ``x_2 = R x_1 + t`` (view 1 -> view 2 frame),
    ``t`` a unit direction; inlier mask over the input matches."""

    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def estimate_relative_pose(
    rays1: np.ndarray, rays2: np.ndarray, *, max_error: float = math.radians(0.5), min_inliers: int = 12, seed: int = 0
) -> PoseFit | None:
    """Relative pose of two central views from matched rays (pycolmap LO-RANSAC, refined).

    ``max_error`` is pycolmap's tangent Sampson error threshold (radians of ray angle).
    Returns ``None`` when RANSAC fails or keeps fewer than ``min_inliers`` matches.
    """
    pycolmap = _pycolmap()
    rays1 = np.ascontiguousarray(rays1, np.float64)
    rays2 = np.ascontiguousarray(rays2, np.float64)
    if rays1.shape != rays2.shape or rays1.ndim != 2 or rays1.shape[1] != 3:
        raise InputError(f"ray arrays must both be (N, 3), got {rays1.shape} and {rays2.shape}")
    if len(rays1) < min_inliers:
        return None
    opts = pycolmap.RANSACOptions()
    opts.max_error = float(max_error)
    opts.confidence = 0.9999
    opts.min_num_trials = 200
    opts.max_num_trials = 5000
    opts.random_seed = int(seed)
    res = pycolmap.estimate_relative_pose(rays1, rays2, opts)
    if res is None:
        return None
    inliers = np.asarray(res["inlier_mask"], bool).ravel()
    if inliers.sum() < min_inliers:
        return None
    pose = res["cam2_from_cam1"]
    refined = pycolmap.refine_relative_pose(pose, rays1, rays2, inliers.reshape(-1, 1))
    if refined is not None and "cam2_from_cam1" in refined:
        pose = refined["cam2_from_cam1"]
    R = np.asarray(pose.rotation.matrix(), np.float64)
    t = np.asarray(pose.translation, np.float64)
    t = t / max(float(np.linalg.norm(t)), 1e-12)
    return PoseFit(R, t, inliers)


@dataclass(frozen=True)
class LevelPoseFit:
    """Result of :func:`estimate_level_pose`: ``x_2 = R_y(yaw) x_1 + t`` between two level views.

    ``yaw`` radians; ``t`` unit (3,) in view 2's frame; ``inliers`` mask over the matches;
    ``rms`` the inliers' RMS angular distance to their epipolar planes (radians); ``sigma`` the
    yaw's 1-sigma uncertainty from the curvature of the inlier cost (radians); ``t_support`` the
    matches with parallax that fixed ``t`` and ``t_sigma`` the 1-sigma angle of ``t`` from them
    (radians; ``inf`` when ``t_support`` is 0).
    """

    yaw: float
    t: np.ndarray
    inliers: np.ndarray
    rms: float
    sigma: float
    t_support: int = 0
    t_sigma: float = math.inf

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())

    @property
    def R(self) -> np.ndarray:
        return np.asarray(rotation_y(self.yaw), np.float64)

    @property
    def centre2_in_1(self) -> np.ndarray:
        """Unit direction from view 1's centre to view 2's centre, in view 1's frame: ``-Rᵀ t``."""
        c = -self.R.T @ self.t
        return c / max(np.linalg.norm(c), 1e-12)


def _epipolar_error(Ra: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """|sin| of the angle between ``b`` and the epipolar plane spanned by ``t`` and ``R a``; broadcasting."""
    n = np.cross(t, Ra)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return np.abs(np.sum(n * b, axis=-1))


def _depths(Ra: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Least-squares depths ``(l1, l2)`` with ``l2 b - l1 R a = t`` per match, ``(N, 2)``."""
    A = np.stack([-Ra, b], axis=-1)  # (N, 3, 2)
    AtA = np.einsum("nki,nkj->nij", A, A)
    Atb = np.einsum("nki,k->ni", A, t)
    det = AtA[:, 0, 0] * AtA[:, 1, 1] - AtA[:, 0, 1] ** 2
    det = np.where(np.abs(det) < 1e-12, 1e-12, det)
    l1 = (AtA[:, 1, 1] * Atb[:, 0] - AtA[:, 0, 1] * Atb[:, 1]) / det
    l2 = (AtA[:, 0, 0] * Atb[:, 1] - AtA[:, 0, 1] * Atb[:, 0]) / det
    return np.stack([l1, l2], -1)


def _constrained_t(cc: np.ndarray, max_ty: float | None) -> tuple[np.ndarray, float]:
    """Unit ``t`` minimising ``|cc t|`` (the smallest right singular vector) with ``|t_y| <= max_ty``.

    When the free minimum is steeper than allowed, the minimum lies on the cone's rim
    ``t = (r cos φ, ±max_ty, r sin φ)``, ``r = sqrt(1 - max_ty²)``: searched over ``φ``.
    Returns ``(t, cost)`` with ``cost = |cc t|²``.
    """
    _, sv, vt = np.linalg.svd(cc, full_matrices=False)
    t = vt[-1]
    if max_ty is None or abs(t[1]) <= max_ty:
        return t, float(sv[-1] ** 2) if len(sv) == 3 else 0.0
    r = math.sqrt(max(1.0 - max_ty**2, 0.0))
    phi = np.linspace(-math.pi, math.pi, 1441)[:-1]
    cands = np.concatenate(
        [np.stack([r * np.cos(phi), np.full_like(phi, sgn * max_ty), r * np.sin(phi)], -1) for sgn in (1.0, -1.0)]
    )
    costs = np.sum((cands @ cc.T) ** 2, axis=1)
    k = int(np.argmin(costs))
    return cands[k], float(costs[k])


def _null_vector_sigma(cc: np.ndarray, t: np.ndarray) -> float:
    """1-sigma angle (radians) of the unit null vector ``t`` of ``cc`` (``cc t ≈ 0``, rows with noise).

    First-order perturbation of the smallest right singular vector: the residual variance
    ``|cc t|² / (n - 2)`` over the two larger squared singular values (in quadrature).
    """
    n = len(cc)
    if n < 3:
        return math.inf
    sv = np.linalg.svd(cc, compute_uv=False)
    var = float(np.sum((cc @ t) ** 2)) / max(n - 2, 1)
    return math.sqrt(var * (1.0 / max(sv[0] ** 2, 1e-18) + 1.0 / max(sv[1] ** 2, 1e-18)))


def estimate_level_pose(
    a: np.ndarray,
    b: np.ndarray,
    *,
    threshold: float = math.radians(0.35),
    yaw_step: float = math.radians(0.5),
    hypotheses: int = 64,
    min_inliers: int = 8,
    min_parallax: float = math.radians(2.0),
    seed: int = 0,
    max_baseline_elevation: float | None = math.radians(60.0),
) -> LevelPoseFit | None:
    """Yaw and translation direction between two gravity-levelled panoramas from matched rays.

    Both views are level, so ``x_2 = R_y(yaw) x_1 + t``: 3 degrees of freedom instead of the
    essential matrix's 5, which keeps the estimate stable with the few tens of correct matches
    that wide-baseline street panoramas give. For every yaw on a ``yaw_step`` grid over 360°,
    ``hypotheses`` translations ``t = c_i × c_j`` with ``c = R a × b`` (two matches fix ``t``
    once the rotation is known) are scored by the number of matches within ``threshold`` of
    their epipolar plane; the best (yaw, t) is refined by least squares on its inliers (a fine
    1-D yaw search with ``t`` the smallest right singular vector of the stacked ``c``), and the
    sign of ``t`` is chosen so that the inliers lie in front of both views (positive depths).
    Distant points agree with any translation, so ``t`` is then re-estimated (RANSAC, then least
    squares) from the matches with at least ``min_parallax`` of parallax alone; ``t_support``
    counts them (0: ``t`` is not determined by the data).

    Returns ``None`` with fewer than ``min_inliers`` inliers.
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    n = len(a)
    if n < max(3, min_inliers):
        return None
    rng = np.random.default_rng(seed)
    yaws = np.arange(-math.pi, math.pi, yaw_step)
    Rs = np.asarray(rotation_y(yaws))  # (Y, 3, 3)
    Ra = np.einsum("yij,nj->yni", Rs, a)  # (Y, N, 3)
    c = np.cross(Ra, b[None])
    c /= np.maximum(np.linalg.norm(c, axis=-1, keepdims=True), 1e-12)
    i = rng.integers(0, n, hypotheses)
    j = rng.integers(0, n, hypotheses)
    keep = i != j
    i, j = i[keep], j[keep]
    t = np.cross(c[:, i], c[:, j])  # (Y, K, 3)
    tn = np.linalg.norm(t, axis=-1, keepdims=True)
    t /= np.maximum(tn, 1e-12)
    s = math.sin(threshold)
    counts = np.zeros(t.shape[:2], np.int64)
    for y0 in range(0, len(yaws), 90):
        e = _epipolar_error(Ra[y0 : y0 + 90, None], b[None, None], t[y0 : y0 + 90, :, None])  # (y, K, N)
        counts[y0 : y0 + 90] = (e <= s).sum(-1)
    counts[tn[..., 0] < 1e-3] = 0  # nearly parallel constraints (duplicate matches) fix no translation
    max_ty = None if max_baseline_elevation is None else math.sin(max_baseline_elevation)
    if max_ty is not None:
        counts[np.abs(t[..., 1]) > max_ty] = 0
    yi, ki = np.unravel_index(int(np.argmax(counts)), counts.shape)
    yaw0, t0 = float(yaws[yi]), t[yi, ki]

    def fit_t(yaw: float, mask: np.ndarray) -> tuple[np.ndarray, float]:
        return _constrained_t(np.cross(a[mask] @ np.asarray(rotation_y(yaw)).T, b[mask]), max_ty)

    inl = _epipolar_error(a @ np.asarray(rotation_y(yaw0)).T, b, t0) <= s
    yaw, tt = yaw0, t0
    for _ in range(3):
        if inl.sum() < min_inliers:
            return None
        fine = yaw + np.linspace(-2 * yaw_step, 2 * yaw_step, 81)
        costs = []
        for y in fine:
            tv, _ = fit_t(float(y), inl)
            err = _epipolar_error(a[inl] @ np.asarray(rotation_y(float(y))).T, b[inl], tv)
            costs.append(float(np.sum(np.minimum(err, s) ** 2)))
        k = int(np.argmin(costs))
        yaw = float(fine[k])
        tt, _ = fit_t(yaw, inl)
        inl = _epipolar_error(a @ np.asarray(rotation_y(yaw)).T, b, tt) <= s
    if inl.sum() < min_inliers:
        return None
    # the translation: distant points (no parallax) agree with any t, so t comes from the matches that
    # show parallax, by its own RANSAC over them (outliers have "parallax" too)
    Ra_all = a @ np.asarray(rotation_y(yaw)).T
    parallax = np.arccos(np.clip(np.sum(Ra_all * b, axis=1), -1.0, 1.0))
    near = np.nonzero(parallax >= min_parallax)[0]
    t_support, t_sigma = 0, math.inf
    if len(near) >= 6:
        cn = np.cross(Ra_all[near], b[near])
        cn /= np.linalg.norm(cn, axis=1, keepdims=True)
        if len(near) <= 120:  # every pair (a few thousand hypotheses) beats 400 random ones at low inlier rates
            ii, jj = np.triu_indices(len(near), 1)
        else:
            ii, jj = rng.integers(0, len(near), 4000), rng.integers(0, len(near), 4000)
        tc = np.cross(cn[ii], cn[jj])
        ok = np.linalg.norm(tc, axis=1) > 1e-3
        if max_ty is not None:
            ok &= np.abs(tc[:, 1]) <= max_ty * np.maximum(np.linalg.norm(tc, axis=1), 1e-12)
        if ok.any():
            tc = tc[ok] / np.linalg.norm(tc[ok], axis=1, keepdims=True)
            Rn, bn = Ra_all[near], b[near]

            def support(tv: np.ndarray) -> tuple[int, np.ndarray, float]:
                """Matches on their epipolar plane AND in front of both views, for +tv or -tv (the larger)."""
                on = _epipolar_error(Rn, bn, tv) <= s
                dd = _depths(Rn, bn, tv)
                pos, neg = on & (dd > 0).all(-1), on & (dd < 0).all(-1)
                return (int(pos.sum()), pos, 1.0) if pos.sum() >= neg.sum() else (int(neg.sum()), neg, -1.0)

            # the same count for all hypotheses at once: depths are linear in t (least squares per match)
            A = np.stack([-Rn, bn], axis=-1)  # (n, 3, 2)
            pinv = np.linalg.pinv(A)  # (n, 2, 3)
            depth = np.einsum("nij,kj->kni", pinv, tc)  # (K, n, 2)
            on = _epipolar_error(Rn[None], bn[None], tc[:, None]) <= s  # (K, n)
            scores = np.maximum((on & (depth > 0).all(-1)).sum(1), (on & (depth < 0).all(-1)).sum(1))
            best_t = tc[int(np.argmax(scores))]
            n_sup, sup, sgn = support(best_t)
            # least squares on the supporters, kept only while it does not lose any (measured: a one-shot refit
            # drifted 26 deg away from a translation with more supporters)
            for _ in range(3):
                if n_sup < 6:
                    break
                t_new, _ = _constrained_t(cn[sup], max_ty)
                n_new, sup_new, sgn_new = support(t_new)
                if n_new < n_sup:
                    break
                best_t, n_sup, sup, sgn = t_new, n_new, sup_new, sgn_new
            if n_sup >= 6:
                tt = sgn * best_t
                t_support = n_sup
                t_sigma = _null_vector_sigma(cn[sup], best_t)
    Ra_in = a[inl] @ np.asarray(rotation_y(yaw)).T
    d = _depths(Ra_in, b[inl], tt)
    if t_support == 0 and np.sum((d > 0).all(-1)) < np.sum((d < 0).all(-1)):
        tt = -tt
    err = _epipolar_error(Ra_in, b[inl], tt)
    rms = float(np.sqrt(np.mean(err**2)))
    # yaw uncertainty: parabola through the cost curve around its minimum (Gauss-Newton curvature)
    h = math.radians(0.05)

    def cost(y: float) -> float:
        return float(np.sum(_epipolar_error(a[inl] @ np.asarray(rotation_y(y)).T, b[inl], fit_t(y, inl)[0]) ** 2))

    curv = (cost(yaw + h) - 2 * cost(yaw) + cost(yaw - h)) / h**2
    dof = max(int(inl.sum()) - 3, 1)
    sigma2 = (cost(yaw) / dof) * 2.0 / curv if curv > 0 else math.inf
    return LevelPoseFit(yaw, tt, inl, rms, math.sqrt(max(sigma2, 0.0)), t_support, t_sigma)
