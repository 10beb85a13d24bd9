"""Cameras of the synthetic photos and probes, and the paper's "best view per 60° sector".

A :class:`Camera` is an ideal OpenCV pinhole (conventions §1) at ``position`` in the scene
frame (:mod:`solidkit.synth.scene`), oriented by ``R = rotation_from_ypr(yaw, pitch, roll)``
(camera -> scene frame, conventions §4). Its *panorama frame* is ``R_y(yaw)``: the scene frame
turned to the camera's heading, with pitch and roll removed (conventions §2).

View selection (paper §3.1 and supplementary §2; :func:`solidkit.synth.views.best_views`): for each of the six 60°
heading sectors, candidate cameras are drawn at random walkable positions (sidewalks and road, away from
obstacles), heading uniform in the sector, height ``1.55 ± 0.05`` m above the floor, pitch
uniform within ±10° (roll within ±``max_roll``), an item buffer is rendered at low resolution
and the candidate with the highest pixel coverage (non-sky fraction) among those showing at
least ``min_categories`` object categories (each on >= 1% of the pixels) is kept.
Deviations (coverage alone rewards staring at a wall or a parked car from 1 m): a candidate
whose largest single object (all parts of a car, tree, building... together) fills more than
``max_object_share`` of the frame (default 0.35), or that shows less than ``min_sky`` sky
(default 5%), is also rejected; cameras keep 1.2 m from trees and street furniture and 1.5 m from cars.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from solidkit.envmap import rotation_from_ypr, rotation_y
from solidkit.envmap.perspective import pixel_rays, scale_intrinsics
from solidkit.synth.mitsuba_variant import mitsuba
from solidkit.synth.scene import CityBlock

__all__ = ["Camera", "pinhole_sensor", "equirect_sensor", "sample_candidate"]


@dataclass
class Camera:
    """A pinhole camera; angles in radians, position in metres (scene frame)."""

    K: np.ndarray
    width: int
    height: int
    position: np.ndarray
    yaw: float
    pitch: float
    roll: float = 0.0

    @property
    def rotation(self) -> np.ndarray:
        """Camera -> scene frame, ``R_y(yaw) R_x(pitch) R_z(roll)``."""
        return np.asarray(rotation_from_ypr(self.yaw, self.pitch, self.roll))

    @property
    def pano_rotation(self) -> np.ndarray:
        """The camera's panorama frame -> scene frame, ``R_y(yaw)``."""
        return np.asarray(rotation_y(self.yaw))

    def scaled(self, width: int, height: int) -> Camera:
        """The same camera at another resolution (same FOV, principal point scaled about pixel centres)."""
        K = scale_intrinsics(self.K, width / self.width, height / self.height)
        return Camera(K, width, height, self.position.copy(), self.yaw, self.pitch, self.roll)

    def rays(self) -> np.ndarray:
        """Camera-frame rays ``v = ((x - cx)/fx, (y - cy)/fy, 1)`` of every pixel, ``(H, W, 3)``.

        :func:`solidkit.envmap.perspective.pixel_rays` of ``K``.
        """
        return pixel_rays(self.K, self.width, self.height)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates ``(..., 2)`` (OpenCV) of scene-frame points ``(..., 3)``."""
        pc = (np.asarray(points) - self.position) @ self.rotation
        uvw = pc @ self.K.T
        return uvw[..., :2] / uvw[..., 2:3]

    def to_json(self) -> dict[str, Any]:
        """JSON-ready pose (angles in degrees, as at every user-facing edge)."""
        return {
            "K": self.K.tolist(),
            "width": self.width,
            "height": self.height,
            "position": [float(v) for v in self.position],
            "yaw_deg": math.degrees(self.yaw),
            "pitch_deg": math.degrees(self.pitch),
            "roll_deg": math.degrees(self.roll),
            "R_scene_from_camera": self.rotation.tolist(),
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Camera:
        return cls(
            np.asarray(d["K"], float),
            int(d["width"]),
            int(d["height"]),
            np.asarray(d["position"], float),
            math.radians(d["yaw_deg"]),
            math.radians(d["pitch_deg"]),
            math.radians(d["roll_deg"]),
        )


def _to_world(mi: Any, R: np.ndarray, t: np.ndarray) -> Any:
    m = np.eye(4)
    m[:3, :3] = R
    m[:3, 3] = t
    return mi.ScalarTransform4f(m.tolist())


def _film(width: int, height: int) -> dict[str, Any]:
    return {
        "type": "hdrfilm",
        "width": int(width),
        "height": int(height),
        "rfilter": {"type": "box"},
        "pixel_format": "rgb",
        "sample_border": False,
    }


def pinhole_sensor(
    cam: Camera, *, jitter: bool = True, seed: int = 0, spp: int = 1, sampler: str = "independent"
) -> Any:
    """A Mitsuba ``sk_pinhole`` sensor for ``cam`` (box filter, ``sampler``: a Mitsuba sampler plugin, e.g.
    ``multijitter`` for less noise at a few samples per pixel)."""
    mi = mitsuba()
    K = cam.K
    return mi.load_dict(
        {
            "type": "sk_pinhole",
            "fx": float(K[0, 0]),
            "fy": float(K[1, 1]),
            "cx": float(K[0, 2]),
            "cy": float(K[1, 2]),
            "jitter": jitter,
            "to_world": _to_world(mi, cam.rotation, cam.position),
            "film": _film(cam.width, cam.height),
            "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(seed)},
        }
    )


def equirect_sensor(
    position: np.ndarray, rotation: np.ndarray, height: int, *, jitter: bool = True, seed: int = 0, spp: int = 1
) -> Any:
    """A Mitsuba ``sk_equirect`` sensor: a ``(height, 2 height)`` panorama at ``position`` whose frame is
    ``rotation``."""
    mi = mitsuba()
    to_world = _to_world(mi, np.asarray(rotation), np.asarray(position))
    return mi.load_dict(
        {
            "type": "sk_equirect",
            "jitter": jitter,
            "to_world": to_world,
            "film": _film(2 * height, height),
            "sampler": {"type": "independent", "sample_count": int(spp), "seed": int(seed)},
        }
    )


def _inside(rects: list[tuple[float, float, float, float]], x: float, z: float) -> bool:
    return any(x0 <= x <= x1 and z0 <= z <= z1 for x0, x1, z0, z1 in rects)


def sample_candidate(
    block: CityBlock,
    rng: np.random.Generator,
    sector: int,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    max_roll_deg: float = 2.0,
) -> Camera:
    """One random camera in heading sector ``sector`` (0..5: yaw in ``[-180 + 60 s, -120 + 60 s)`` degrees)."""
    areas = np.array([(r[1] - r[0]) * (r[3] - r[2]) for r in block.walkable])
    for _ in range(1000):
        r = block.walkable[int(rng.choice(len(areas), p=areas / areas.sum()))]
        x, z = rng.uniform(r[0], r[1]), rng.uniform(r[2], r[3])
        if not _inside(block.obstacles, x, z):
            break
    h = rng.uniform(1.50, 1.60)
    yaw = math.radians(-180.0 + 60.0 * sector + rng.uniform(0.0, 60.0))
    pitch = math.radians(rng.uniform(-10.0, 10.0))
    roll = math.radians(rng.uniform(-max_roll_deg, max_roll_deg))
    return Camera(K.copy(), width, height, np.array([x, r[4] - h, z]), yaw, pitch, roll)
