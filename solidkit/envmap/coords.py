"""Equirectangular coordinates, directions, solid angles and rotations.

The formulas of ``docs/conventions.md`` §2-4, written once for NumPy and torch alike
through the array API (``array_api_compat``): pass NumPy arrays and get NumPy arrays, pass
torch tensors (any device, batched, differentiable) and get tensors.

Coordinates are *continuous image coordinates*: the pixel in column ``u`` and row ``v``
covers ``[u, u+1) x [v, v+1)`` and has its centre at ``(u + 0.5, v + 0.5)``.
Angles are radians. Directions are unit vectors in the panorama frame
(x right, y down, z forward), stored in a trailing axis of size 3.
"""

from __future__ import annotations

import math
from typing import Any

import array_api_compat
import numpy as np

from solidkit.errors import InputError

CONVENTIONS_VERSION = 1

__all__ = [
    "CONVENTIONS_VERSION",
    "namespace",
    "wrap_angle",
    "module_namespace",
    "angles_from_coords",
    "coords_from_angles",
    "direction_from_angles",
    "angles_from_direction",
    "coords_from_direction",
    "direction_from_coords",
    "angles_grid",
    "direction_grid",
    "solid_angle",
    "rotation_x",
    "rotation_y",
    "rotation_z",
    "rotation_from_ypr",
    "ypr_from_rotation",
    "rotation_from_rotvec",
    "angular_distance",
]


def namespace(*arrays: Any) -> Any:
    """Array-API namespace of ``arrays`` (NumPy or torch); Python scalars are ignored.

    Examples
    --------
    >>> namespace(np.zeros(3), 2.0).__name__
    'numpy'
    """
    tensors = [a for a in arrays if not isinstance(a, (int, float))]
    if all(isinstance(a, (np.ndarray, np.generic)) for a in tensors):
        # NumPy >= 2 is an array-API namespace itself; array_api_compat's numpy wrapper costs ~0.1 s to import
        return np
    return array_api_compat.array_namespace(*arrays)


def module_namespace(module: Any) -> Any:
    """Array-API namespace for a module given by the caller (``numpy`` or ``torch``).

    Examples
    --------
    >>> xp = module_namespace(np)
    >>> xp.__name__
    'numpy'
    """
    return namespace(module.zeros(0))


def angles_from_coords(x: Any, y: Any, height: int) -> tuple[Any, Any]:
    """Azimuth and elevation of continuous equirect coordinates (conventions §3).

    Parameters
    ----------
    x, y : array (...)
        Continuous coordinates; pixel ``(u, v)`` has its centre at ``(u + 0.5, v + 0.5)``.
    height : int
        Panorama height ``H`` (width ``W = 2H``).

    Returns
    -------
    (phi, theta) : arrays (...)
        Azimuth in ``[-pi, pi)`` (0 = forward, positive to the right) and elevation in
        ``[-pi/2, pi/2]`` (positive up), radians.

    Examples
    --------
    >>> phi, theta = angles_from_coords(192.0, 32.0, 128)  # W = 256
    >>> round(math.degrees(phi), 9), round(math.degrees(theta), 9)
    (90.0, 45.0)
    """
    phi = x * (math.pi / height) - math.pi
    theta = math.pi / 2 - y * (math.pi / height)
    return phi, theta


def coords_from_angles(phi: Any, theta: Any, height: int) -> tuple[Any, Any]:
    """Inverse of :func:`angles_from_coords`; ``x`` is wrapped into ``[0, W)``.

    Examples
    --------
    >>> x, y = coords_from_angles(math.pi / 2, math.pi / 4, 128)
    >>> float(x), float(y)
    (192.0, 32.0)
    """
    width = 2 * height
    x = ((phi + math.pi) * (height / math.pi)) % width
    y = (math.pi / 2 - theta) * (height / math.pi)
    return x, y


def direction_from_angles(phi: Any, theta: Any) -> Any:
    """Unit direction ``(cos t sin p, -sin t, cos t cos p)``; shape ``(..., 3)``.

    Examples
    --------
    >>> np.round(direction_from_angles(math.pi / 2, 0.0), 12) + 0.0  # azimuth 90°: right
    array([1., 0., 0.])
    >>> np.round(direction_from_angles(0.0, math.pi / 2), 12) + 0.0  # elevation 90°: up (-y)
    array([ 0., -1.,  0.])
    """
    xp = namespace(phi, theta)
    ct = xp.cos(theta)
    return xp.stack([ct * xp.sin(phi), -xp.sin(theta), ct * xp.cos(phi)], axis=-1)


def angles_from_direction(d: Any) -> tuple[Any, Any]:
    """Azimuth ``atan2(dx, dz)`` and elevation ``asin(-dy)`` of (not necessarily unit) ``d (..., 3)``.

    Examples
    --------
    >>> phi, theta = angles_from_direction(np.array([1.0, -1.0, 0.0]))  # right and up
    >>> round(math.degrees(phi), 9), round(math.degrees(theta), 9)
    (90.0, 45.0)
    """
    xp = namespace(d)
    norm = xp.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + d[..., 2] ** 2)
    phi = xp.atan2(d[..., 0], d[..., 2])
    phi = xp.where(phi >= math.pi, phi - 2 * math.pi, phi)  # atan2(+0, -1) = +pi; keep [-pi, pi)
    theta = xp.asin(xp.clip(-d[..., 1] / norm, -1.0, 1.0))
    return phi, theta


def coords_from_direction(d: Any, height: int) -> tuple[Any, Any]:
    """Continuous equirect coordinates ``(x, y)`` of directions ``d (..., 3)``.

    Examples
    --------
    >>> x, y = coords_from_direction(np.array([1.0, 0.0, 0.0]), 128)
    >>> float(x), float(y)
    (192.0, 64.0)
    """
    return coords_from_angles(*angles_from_direction(d), height)


def direction_from_coords(x: Any, y: Any, height: int) -> Any:
    """Unit directions ``(..., 3)`` of continuous equirect coordinates.

    Examples
    --------
    >>> np.round(direction_from_coords(128.0, 64.0, 128), 12) + 0.0  # the centre is forward
    array([0., 0., 1.])
    """
    return direction_from_angles(*angles_from_coords(x, y, height))


def _pixel_centres(height: int, xp: Any, **kw: Any) -> tuple[Any, Any]:
    width = 2 * height
    x = xp.arange(width, **kw) + 0.5
    y = xp.arange(height, **kw) + 0.5
    yy, xx = xp.meshgrid(y, x, indexing="ij")
    return xx, yy


def angles_grid(height: int, xp: Any = np, **kw: Any) -> tuple[Any, Any]:
    """Azimuth and elevation of every pixel centre, each ``(H, 2H)``.

    ``xp`` is ``numpy`` (default) or ``torch``; ``kw`` go to ``xp.arange`` (``dtype``, ``device``).

    Examples
    --------
    >>> phi, theta = angles_grid(2)
    >>> np.degrees(phi)[0]
    array([-135.,  -45.,   45.,  135.])
    >>> np.degrees(theta)[:, 0]
    array([ 45., -45.])
    """
    kw.setdefault("dtype", xp.float64 if xp is np else xp.float32)
    xx, yy = _pixel_centres(height, module_namespace(xp), **kw)
    return angles_from_coords(xx, yy, height)


def direction_grid(height: int, xp: Any = np, **kw: Any) -> Any:
    """Unit direction of every pixel centre, ``(H, 2H, 3)``, in the panorama frame.

    The same formula as :func:`direction_from_angles`, evaluated on one row of azimuths and one
    column of elevations (the grid is separable), so the trigonometry costs O(H + W), not O(HW).

    Examples
    --------
    >>> d = direction_grid(64)
    >>> d.shape
    (64, 128, 3)
    >>> bool(np.allclose(np.linalg.norm(d, axis=-1), 1.0))
    True
    """
    kw.setdefault("dtype", xp.float64 if xp is np else xp.float32)
    ns = module_namespace(xp)
    phi, _ = angles_from_coords(ns.arange(2 * height, **kw) + 0.5, 0.0, height)
    _, theta = angles_from_coords(0.0, ns.arange(height, **kw) + 0.5, height)
    row = direction_from_angles(phi, ns.zeros_like(phi))  # (W, 3) at elevation 0
    ct, st = ns.cos(theta)[:, None], ns.sin(theta)[:, None]  # (H, 1)
    return ns.stack([ct * row[None, :, 0], ns.broadcast_to(-st, (height, 2 * height)), ct * row[None, :, 2]], axis=-1)


def solid_angle(height: int, xp: Any = np, **kw: Any) -> Any:
    """Exact solid angle of every pixel, ``(H, 2H)`` steradians, summing to ``4 pi``.

    ``Omega(v) = (2 pi / W) (sin theta_top(v) - sin theta_bottom(v))``.

    Examples
    --------
    >>> omega = solid_angle(64)
    >>> omega.shape
    (64, 128)
    >>> round(float(omega.sum()) / (4 * math.pi), 12)
    1.0
    """
    kw.setdefault("dtype", xp.float64 if xp is np else xp.float32)
    ns = module_namespace(xp)
    edges = ns.arange(height + 1, **kw)
    s = ns.sin(math.pi / 2 - edges * (math.pi / height))
    row = (s[:-1] - s[1:]) * (math.pi / height)
    return ns.broadcast_to(row[:, None], (height, 2 * height))


def _elementary(angle: Any, axes: tuple[int, int]) -> Any:
    """Right-handed rotation by ``angle`` about the axis not in ``axes``; ``(..., 3, 3)``."""
    xp = namespace(angle)
    angle = xp.asarray(angle, dtype=xp.float64) if isinstance(angle, (int, float)) else angle
    c, s = xp.cos(angle), xp.sin(angle)
    one, zero = xp.ones_like(c), xp.zeros_like(c)
    i, j = axes
    rows = [[one, zero, zero], [zero, one, zero], [zero, zero, one]]
    rows[i][i], rows[i][j] = c, -s
    rows[j][i], rows[j][j] = s, c
    return xp.stack([xp.stack(r, axis=-1) for r in rows], axis=-2)


def rotation_x(angle: Any) -> Any:
    """``R_x``: right-handed rotation about x (right); maps forward z toward -y (up) for angle > 0.

    Examples
    --------
    >>> np.round(rotation_x(math.radians(90.0)), 12) + 0.0  # its third column: forward turns up (-y)
    array([[ 1.,  0.,  0.],
           [ 0.,  0., -1.],
           [ 0.,  1.,  0.]])
    """
    return _elementary(angle, (1, 2))


def rotation_y(angle: Any) -> Any:
    """``R_y``: right-handed rotation about y (down); maps forward z toward +x (right) for angle > 0.

    Examples
    --------
    >>> np.round(rotation_y(math.pi / 2) @ [0.0, 0.0, 1.0], 12) + 0.0  # forward turns right
    array([1., 0., 0.])
    """
    return _elementary(angle, (2, 0))


def rotation_z(angle: Any) -> Any:
    """``R_z``: right-handed rotation about z (forward); maps right x toward +y (down) for angle > 0.

    Examples
    --------
    >>> R = rotation_z(np.array([0.0, math.pi / 2]))  # a batch of two angles
    >>> R.shape
    (2, 3, 3)
    >>> np.round(R[1] @ [1.0, 0.0, 0.0], 12) + 0.0  # right turns down
    array([0., 1., 0.])
    """
    return _elementary(angle, (0, 1))


def rotation_from_ypr(yaw: Any, pitch: Any = 0.0, roll: Any = 0.0) -> Any:
    """``R = R_y(yaw) R_x(pitch) R_z(roll)`` (conventions §4), radians; ``(..., 3, 3)``.

    ``R`` maps camera-frame vectors to panorama-frame vectors: a camera with this orientation
    looks at azimuth ``yaw`` and elevation ``pitch``, and ``roll > 0`` turns its right axis down.
    Non-finite Python-number angles raise :class:`~solidkit.errors.InputError`.

    Examples
    --------
    >>> R = rotation_from_ypr(math.radians(90.0), math.radians(30.0))  # look right, 30° up
    >>> np.round(R @ [0.0, 0.0, 1.0], 6) + 0.0
    array([ 0.866025, -0.5     ,  0.      ])
    """
    arrays = [a for a in (yaw, pitch, roll) if not isinstance(a, (int, float))]
    if arrays:  # Python floats follow the array arguments' backend, dtype and device
        xp = namespace(*arrays)
        like = arrays[0]
        yaw, pitch, roll = (
            xp.asarray(a, dtype=like.dtype, device=array_api_compat.device(like)) if isinstance(a, (int, float)) else a
            for a in (yaw, pitch, roll)
        )
    elif not all(math.isfinite(a) for a in (yaw, pitch, roll)):
        raise InputError(f"rotation angles must be finite numbers, got yaw, pitch, roll = {yaw}, {pitch}, {roll}")
    return rotation_y(yaw) @ rotation_x(pitch) @ rotation_z(roll)


def ypr_from_rotation(R: Any) -> tuple[Any, Any, Any]:
    """Inverse of :func:`rotation_from_ypr`: ``(yaw, pitch, roll)`` in radians.

    Pitch is in ``[-pi/2, pi/2]``; at pitch = ±pi/2 (gimbal lock) roll is returned as 0.

    Examples
    --------
    >>> yaw, pitch, roll = ypr_from_rotation(rotation_from_ypr(0.3, -0.2, 0.1))
    >>> round(float(yaw), 12), round(float(pitch), 12), round(float(roll), 12)
    (0.3, -0.2, 0.1)
    """
    xp = namespace(R)
    # forward = R e_z = (cp sy, -sp, cp cy); right = R e_x = (cy cr + sy sp sr, cp sr, -sy cr + cy sp sr)
    fwd = R[..., :, 2]
    yaw, pitch = angles_from_direction(fwd)
    roll = xp.atan2(R[..., 1, 0], R[..., 1, 1])
    return yaw, pitch, roll


def rotation_from_rotvec(w: Any) -> Any:
    """Rotation matrix of a rotation vector (Rodrigues' formula), ``(..., 3)`` radians -> ``(..., 3, 3)``.

    ``R = I + sin(a) [k]x + (1 - cos(a)) [k]x²`` with ``a = |w|`` the angle and ``k = w / a`` the
    axis (right-handed); ``w = 0`` gives the identity. Lists are taken as NumPy arrays.

    Examples
    --------
    >>> import numpy as np
    >>> R = rotation_from_rotvec(np.array([0.0, np.pi / 2, 0.0]))  # 90° about y (down)
    >>> np.round(R @ [0.0, 0.0, 1.0], 12) + 0.0  # forward turns to the right, like rotation_y
    array([1., 0., 0.])
    """
    if isinstance(w, (list, tuple)):
        w = np.asarray(w, dtype=np.float64)
    xp = namespace(w)
    a = xp.sqrt(xp.sum(w * w, axis=-1))
    k = w / xp.where(a > 1e-12, a, xp.ones_like(a))[..., None]
    zero = xp.zeros_like(a)
    K = xp.stack(
        [
            xp.stack([zero, -k[..., 2], k[..., 1]], axis=-1),
            xp.stack([k[..., 2], zero, -k[..., 0]], axis=-1),
            xp.stack([-k[..., 1], k[..., 0], zero], axis=-1),
        ],
        axis=-2,
    )
    eye = xp.eye(3, dtype=w.dtype, device=array_api_compat.device(w))
    s, c = xp.sin(a)[..., None, None], xp.cos(a)[..., None, None]
    return eye + s * K + (1 - c) * (K @ K)


def wrap_angle(a: Any, period: float = 2 * math.pi) -> Any:
    """Angles (or angle differences) ``a`` wrapped into ``[-period / 2, period / 2)``; floats, arrays or
    tensors. ``period=360.0`` for degrees; ``abs(wrap_angle(a - b))`` is the azimuth gap in ``[0, period / 2]``.

    Examples
    --------
    >>> wrap_angle(350.0 - 10.0, 360.0), abs(wrap_angle(-179.0 - 179.0, 360.0))
    (-20.0, 2.0)
    """
    half = period / 2
    return (a + half) % period - half


def angular_distance(a: Any, b: Any) -> Any:
    """Angle in radians between directions ``a`` and ``b`` (``(..., 3)``), robust near 0 and pi.

    Examples
    --------
    >>> a, b = np.array([1.0, 0.0, 0.0]), np.array([1.0, 1e-9, 0.0])
    >>> float(angular_distance(a, b))  # exact near 0, where acos(a . b) returns 0
    1e-09
    >>> round(math.degrees(float(angular_distance(a, np.array([0.0, 0.0, 1.0])))), 9)
    90.0
    """
    xp = namespace(a, b)
    cross = xp.linalg.cross(a, b)
    return xp.atan2(xp.sqrt(xp.sum(cross * cross, axis=-1)), xp.sum(a * b, axis=-1))
