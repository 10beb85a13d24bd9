"""Camera orientation from capture metadata: Ricoh axes, gravity vs pitch/roll, and the pose fields of a file.

Frames are described in :mod:`solidkit.camera.metadata` (Ricoh X right, Y front lens, Z up;
ours x right, y down, z forward).
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np

from solidkit.envmap.coords import rotation_from_rotvec, rotation_from_ypr

__all__ = ["RICOH_TO_OURS", "gravity_from_pitch_roll", "pitch_roll_from_gravity", "pose_fields"]

#: ``v_ours = RICOH_TO_OURS @ v_ricoh`` (Ricoh X right, Y front, Z up -> ours x right, y down, z front).
RICOH_TO_OURS = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def gravity_from_pitch_roll(pitch: float, roll: float) -> np.ndarray:
    """Gravity in Ricoh camera axes for a front-lens frame with ``R_cam = R(0, pitch, roll)`` (radians).

    ``g_ours_cam = R_camᵀ (0, 1, 0)`` (gravity is +y in the level frame), then
    ``g_ricoh = RICOH_TO_OURSᵀ g_ours_cam``.
    """
    R = np.asarray(rotation_from_ypr(0.0, float(pitch), float(roll)))
    return cast(np.ndarray, RICOH_TO_OURS.T @ (R.T @ np.array([0.0, 1.0, 0.0])))


def pitch_roll_from_gravity(g_ricoh: Any) -> tuple[float, float]:
    """Inverse of :func:`gravity_from_pitch_roll` (radians); ``g`` need not be unit length."""
    g = RICOH_TO_OURS @ np.asarray(g_ricoh, dtype=np.float64)
    g = g / np.linalg.norm(g)
    # g_cam = R_z(roll)^T R_x(pitch)^T e_y = (sin r cos p, cos r cos p, -sin p)
    pitch = math.asin(max(-1.0, min(1.0, -g[2])))
    roll = math.atan2(g[0], g[1])
    return pitch, roll


def pose_fields(theta: dict[int, Any], gpano: dict[str, Any], warnings: list[str]) -> dict[str, Any]:
    """Gravity and heading of a capture from its RICOH THETA IFD tags, else its GPano pose.

    Returns the :class:`~solidkit.camera.metadata.CaptureMetadata` fields ``pitch_deg``,
    ``roll_deg``, ``gravity`` (Ricoh axes), ``gravity_source`` and ``heading_deg`` that could be
    read; problems are appended to ``warnings``.
    """
    meta: dict[str, Any] = {}
    # gravity: Ricoh angle pair (S/SC; verified against GPano pose), rotation vector (V/Z1/X), GPano pose.
    pitch = roll = None
    angles = theta.get(0x0003)
    rvec = theta.get(0x0109)
    if (
        isinstance(angles, list)
        and len(angles) == 2
        and all(isinstance(a, (int, float)) and math.isfinite(a) and -360 <= a <= 360 for a in angles)
    ):
        # Ricoh writes angles in [0, 360): 359.6 is -0.4 (wrapped to (-180, 180])
        angles = [a - 360.0 if a > 180 else a + 360.0 if a <= -180 else a for a in angles]
    if isinstance(angles, list) and len(angles) == 2 and all(math.isfinite(a) and abs(a) <= 180 for a in angles):
        roll, pitch = float(angles[0]), float(angles[1])
        meta["gravity_source"] = "ricoh:0x0003 [roll, pitch] deg"
    elif (
        isinstance(rvec, list)
        and len(rvec) == 3
        and all(math.isfinite(a) for a in rvec)
        and np.linalg.norm(rvec) < 2 * math.pi
    ):
        # Ricoh: "Zenith Direction (= Rotation Vector)" in camera axes. We read it as the rotation
        # taking the level frame's up (Z) to the camera's measured zenith: zenith_cam = R e_z.
        R = rotation_from_rotvec(np.asarray(rvec, dtype=np.float64))
        g = -(R @ np.array([0.0, 0.0, 1.0]))
        p_rad, r_rad = pitch_roll_from_gravity(g)
        pitch, roll = math.degrees(p_rad), math.degrees(r_rad)
        meta["gravity_source"] = "ricoh:0x0109 rotation vector"
        warnings.append("gravity_rotvec_unverified: 0x0109 sense not verified against a sample file")
    elif isinstance(angles, list) or isinstance(rvec, list):
        warnings.append("bad_gravity: Ricoh zenith fields present but invalid")
    if pitch is None and ("PosePitchDegrees" in gpano or "PoseRollDegrees" in gpano):
        try:
            pitch = float(gpano.get("PosePitchDegrees", 0.0))
            roll = float(gpano.get("PoseRollDegrees", 0.0))
            meta["gravity_source"] = "gpano:PosePitchDegrees/PoseRollDegrees"
        except (TypeError, ValueError):
            warnings.append("bad_gravity: GPano pose not numeric")
            pitch = roll = None
    if pitch is not None and roll is not None:
        meta["pitch_deg"], meta["roll_deg"] = pitch, roll
        meta["gravity"] = [float(x) for x in gravity_from_pitch_roll(math.radians(pitch), math.radians(roll))]
    comp = theta.get(0x0004)
    if isinstance(comp, list) and comp and math.isfinite(comp[0]) and 0 <= comp[0] <= 360:
        meta["heading_deg"] = float(comp[0])
    elif isinstance(gpano.get("PoseHeadingDegrees"), (int, float)):
        meta["heading_deg"] = float(gpano["PoseHeadingDegrees"])

    return meta
