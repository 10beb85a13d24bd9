"""What a field team can do in a virtual scene: where a probe can stand, and glass facades that glint.

Used by :mod:`solidkit.synth.campaign` so that the virtual campaign follows
``docs/field-protocol.md``:

- :func:`reachable_mask` / :func:`pick_reachable_probes`: probes stand on surfaces a person can
  reach (the road, sidewalks, markings, bench seats: up-facing, at most
  ``max_surface_height_m`` above the ground, within ``max_distance_m`` of the photo camera),
  with the lens ``lens_height_m`` (10 cm) above the surface along its normal (the paper's
  synthetic probes are 10 cm off the surface), not under anything (nothing within 2 m above
  the lens) and not hugging a wall, curb face or object (no geometry within
  ``clearance_m`` horizontally at lens height).
- :func:`add_glass_facades` / :func:`glint_direction`: a street lined with curtain-wall glass
  on both sides (the side that faces the sun shows the sun's mirror image: a *glint*, a second
  sun-like spot in low-exposure frames that sun detection must reject). A vertical mirror
  with outward normal ``n`` shows the sun ``s`` at ``g = s - 2 (s·n) n`` (same elevation,
  azimuth mirrored), seen from ``p`` when the ray ``p + t g`` meets the glass first and the
  sun reaches that point.

Frames: the scene frame of :mod:`solidkit.synth.scene` (x east, y down, z north; ground y = 0).
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

from solidkit.synth.cameras import Camera
from solidkit.synth.materials import materials_of
from solidkit.synth.sample import pick_probe_pixels
from solidkit.synth.scene import CATEGORIES, CityBlock, box

__all__ = [
    "REACHABLE_CATEGORIES",
    "GlassPanel",
    "reachable_mask",
    "pick_reachable_probes",
    "add_glass_facades",
    "glint_direction",
    "first_hit",
    "occluded",
]

REACHABLE_CATEGORIES = ("road", "sidewalk", "marking", "bench")
_UP = np.array([0.0, -1.0, 0.0])


def first_hit(mi: Any, scene: Any, origin: np.ndarray, direction: np.ndarray, maxt: float = math.inf) -> float | None:
    """Distance (m) to the first surface along the ray, or None."""
    ray = mi.Ray3f(mi.Point3f(*[float(v) for v in origin]), mi.Vector3f(*[float(v) for v in direction]))
    if math.isfinite(maxt):
        ray.maxt = float(maxt)
    si = scene.ray_intersect(ray)
    valid = bool(np.asarray(si.is_valid()).ravel()[0])
    return float(np.asarray(si.t).ravel()[0]) if valid else None


def occluded(mi: Any, scene: Any, origin: np.ndarray, direction: np.ndarray, maxt: float = math.inf) -> bool:
    """Does geometry block the ray from ``origin`` toward ``direction`` (within ``maxt`` m)?"""
    return first_hit(mi, scene, origin, direction, maxt) is not None


def reachable_mask(
    block: CityBlock,
    cam: Camera,
    buf: dict[str, np.ndarray],
    *,
    max_surface_height_m: float = 1.0,
    max_distance_m: float = 25.0,
    max_slope_deg: float = 20.0,
) -> np.ndarray:
    """Photo pixels ``(H, W)`` bool whose surface a person can reach (module docstring; clearance not tested).

    ``buf``: :func:`solidkit.synth.sample.render_buffers` of ``cam`` (``hit``, ``t``, ``normal_world``, ``label``).
    """
    hit = buf["hit"]
    v = cam.rays()
    d = (v / np.linalg.norm(v, axis=-1, keepdims=True)) @ cam.rotation.T
    point = cam.position + buf["t"][..., None].astype(np.float64) * d
    up = buf["normal_world"].astype(np.float64) @ _UP >= math.cos(math.radians(max_slope_deg))
    low = -point[..., 1] <= max_surface_height_m
    near = np.hypot(point[..., 0] - cam.position[0], point[..., 2] - cam.position[2]) <= max_distance_m
    cats = block.category_of(buf["label"])
    allowed = np.isin(cats, [CATEGORIES.index(c) for c in REACHABLE_CATEGORIES])
    return hit & up & low & near & allowed


def pick_reachable_probes(
    mi: Any,
    scene: Any,
    block: CityBlock,
    cam: Camera,
    buf: dict[str, np.ndarray],
    n: int,
    rng: np.random.Generator,
    *,
    lens_height_m: float = 0.10,
    clearance_m: float = 0.30,
    min_spacing_m: float = 1.0,
    max_surface_height_m: float = 1.0,
    max_distance_m: float = 25.0,
    rounds: int = 40,
) -> list[dict[str, Any]]:
    """Up to ``n`` probe placements: one per photo quadrant first (:func:`pick_probe_pixels`), then anywhere.

    Each candidate pixel's lens position must be clear (module docstring) and at least
    ``min_spacing_m`` from the photo camera and the probes already chosen. Returns dicts with
    ``pixel`` ``[x, y]`` (int), ``quadrant`` (-1 after the first round), ``point`` (surface
    point), ``normal`` (unit, scene frame) and ``position`` (the lens: ``point + lens_height_m *
    normal``).
    """
    mask = reachable_mask(block, cam, buf, max_surface_height_m=max_surface_height_m, max_distance_m=max_distance_m)
    v = cam.rays()
    chosen: list[dict[str, Any]] = []
    taken = [np.asarray(cam.position, np.float64)]
    horizontal = [np.array([math.cos(a), 0.0, math.sin(a)]) for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)]
    for r in range(rounds):
        if len(chosen) >= n or not mask.any():
            break
        picks = pick_probe_pixels(mask, rng, 0.05)
        rng.shuffle(picks)
        for p in picks:
            if len(chosen) >= n:
                break
            x, y = p["pixel"]
            mask[y, x] = False
            d = cam.rotation @ (v[y, x] / np.linalg.norm(v[y, x]))
            point = cam.position + float(buf["t"][y, x]) * d
            normal = buf["normal_world"][y, x].astype(np.float64)
            normal /= np.linalg.norm(normal)
            lens = point + lens_height_m * normal
            if min(np.linalg.norm(lens - q) for q in taken) < min_spacing_m:
                continue
            if occluded(mi, scene, lens, _UP, 2.0) or any(
                occluded(mi, scene, lens, h, clearance_m) for h in horizontal
            ):
                continue
            taken.append(lens)
            chosen.append(
                {
                    "pixel": [int(x), int(y)],
                    "quadrant": int(p["quadrant"]) if r == 0 else -1,
                    "point": point,
                    "normal": normal,
                    "position": lens,
                    "label": int(buf["label"][y, x]),
                }
            )
    return chosen


class GlassPanel:
    """A vertical glass rectangle ``x = x_plane`` (outward normal ``(nx, 0, 0)``), ``y0..y1``, ``z0..z1`` (m)."""

    def __init__(self, x_plane: float, nx: float, y0: float, y1: float, z0: float, z1: float):
        self.x_plane, self.nx, self.y0, self.y1, self.z0, self.z1 = x_plane, nx, y0, y1, z0, z1

    @property
    def normal(self) -> np.ndarray:
        return np.array([self.nx, 0.0, 0.0])

    def contains(self, p: np.ndarray, tol: float = 0.05) -> bool:
        return (
            abs(p[0] - self.x_plane) <= tol
            and self.y0 - tol <= p[1] <= self.y1 + tol
            and self.z0 - tol <= p[2] <= self.z1 + tol
        )

    def to_json(self) -> dict[str, float]:
        return {
            "x_plane": self.x_plane,
            "normal_x": self.nx,
            "y0": self.y0,
            "y1": self.y1,
            "z0": self.z0,
            "z1": self.z1,
        }


def add_glass_facades(
    block: CityBlock,
    rng: np.random.Generator,
    *,
    from_height_m: float = 0.6,
    offset_m: float = 0.03,
    thickness_m: float = 0.02,
) -> tuple[CityBlock, list[GlassPanel]]:
    """A copy of ``block`` whose street-facing building fronts (both sides) carry curtain-wall glass.

    Each building box standing on the ground with its front within 2 m of the sidewalks' outer
    edge gets a thin glass box ``offset_m`` in front of it, from ``from_height_m`` up to its
    roof (material ``curtainglass_*``, category ``building``, part of that building's object).
    Returns ``(block, panels)``; the input block is not modified.
    """
    out = copy.copy(block)
    out.parts = list(block.parts)
    edge = max(max(abs(w[0]), abs(w[1])) for w in block.walkable) if block.walkable else 8.0
    glass = materials_of("curtainglass")
    panels: list[GlassPanel] = []
    for part in block.parts:
        if part.category != "building":
            continue
        lo, hi = part.vertices.min(axis=0), part.vertices.max(axis=0)
        if abs(hi[1]) > 1e-3:  # not standing on the ground (a setback upper volume)
            continue
        for side in (-1.0, 1.0):
            front = lo[0] if side > 0 else hi[0]
            if side * front <= 0 or not edge - 0.5 <= abs(front) <= edge + 2.0:
                continue
            height = -lo[1]
            xg = front - side * offset_m  # the glass stands in front of the facade
            x_lo, x_hi = sorted((xg, xg - side * thickness_m))
            mat = glass[int(rng.integers(len(glass)))]
            gp = box((x_lo, -height, lo[2]), (x_hi, -from_height_m, hi[2]), mat, "building")
            gp.group = part.group
            out.parts.append(gp)
            gp.label = len(out.parts) - 1
            panels.append(GlassPanel(xg, -side, -height, -from_height_m, float(lo[2]), float(hi[2])))
    return out, panels


def glint_direction(
    mi: Any, scene: Any, position: np.ndarray, sun: np.ndarray, panels: list[GlassPanel]
) -> np.ndarray | None:
    """Scene-frame unit direction of a sun glint seen from ``position``, or None (module docstring)."""
    for panel in panels:
        n = panel.normal
        if float(sun @ n) <= 0.0:  # this glass faces away from the sun
            continue
        g = sun - 2.0 * float(sun @ n) * n
        if float(g @ n) >= 0.0:
            continue
        t = first_hit(mi, scene, position, g)
        if t is None:
            continue
        hit = position + t * g
        if not panel.contains(hit):
            continue
        if not occluded(mi, scene, hit + 0.05 * n, sun):
            return g / np.linalg.norm(g)
    return None
