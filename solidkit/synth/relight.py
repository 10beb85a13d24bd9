"""Virtual objects rendered under a local light probe, for relighting a photo (differential rendering).

A *relight view* puts one object on a horizontal ground plane (the shadow catcher) at the origin of the
probe's panorama frame (docs/conventions.md §2: x right, y down, z forward; the plane is ``y = 0``, the
object stands on it, ``y < 0``) and looks at it from the direction the photo's camera sees the probe's
pixel from: the same azimuth, a depression of the pixel's ray clamped to ``[min, max]_depression_deg``
(a ray at or above the horizon would see the plane edge-on), and the photo's roll. The probe
``(H, 2H, 3)`` (linear HDR, panorama frame) is the only light (Mitsuba ``envmap``, mapped as in
:mod:`solidkit.synth.lighting`).

:func:`render_objects` path-traces, at ``size x size`` pixels, the plane with the object and the plane
alone (the same seed), and labels each pixel: object, plane or background (the probe seen directly).
Differential rendering (Debevec, "Rendering synthetic objects into real scenes", SIGGRAPH 1998) then
composites: object pixels take the render with the object; elsewhere the photo gets the difference
(with - without: the object's shadow and bounce light) added, scaled per channel so that the virtual ground
matches the photo's at the probe's pixel (:func:`composite`). Renders use 64 multi-jittered samples per
pixel by default in the evaluation, path depth 4, and the probe's upper half only (:func:`upper_hemisphere`).

Objects (:data:`OBJECTS`), all about one unit tall, generated here (no files):

- ``diffuse_sphere``: a Lambertian sphere (albedo 0.8), radius 0.5;
- ``glossy_sphere``: a blue plastic sphere (GGX roughness 0.1), radius 0.5;
- ``bunny``: a procedural bunny-like mesh (body, head, ears, tail: overlapping ellipsoids), clay-coloured,
  turned three-quarters to the viewer; its ears cast shadows on its back.

The plane is a grey Lambertian (albedo 0.3). Units: the renders are in the probe's units (a probe scaled
by ``k`` renders ``k`` times brighter).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from solidkit.envmap.coords import angles_from_direction, rotation_y
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.envmap.sun import luminance
from solidkit.synth.cameras import Camera, pinhole_sensor
from solidkit.synth.lighting import Lighting
from solidkit.synth.mitsuba_variant import mitsuba, variant
from solidkit.synth.plugins import BUFFER_AOVS
from solidkit.synth.render import integrator, render_rgb

__all__ = [
    "OBJECTS",
    "PLANE_ALBEDO",
    "RelightView",
    "ObjectRender",
    "relight_view",
    "object_mesh",
    "render_objects",
    "composite",
    "upper_hemisphere",
    "square_spp",
    "renderer_name",
]

OBJECTS = ("diffuse_sphere", "glossy_sphere", "bunny")
PLANE_ALBEDO = 0.3
PLANE_HALF_SIZE = 60.0
LABEL_PLANE, LABEL_OBJECT = 0, 1


@dataclass(frozen=True)
class RelightView:
    """Where the virtual camera looks from; angles in radians.

    azimuth, depression: of the viewing direction (camera towards the object) in the probe's panorama frame;
    roll: the photo camera's; size: the render's side in pixels; fov_deg: its field of view (degrees);
    distance: camera to the object's centre (units of the object, ~1 tall: it fills ~2/3 of the height).
    """

    azimuth: float
    depression: float
    roll: float = 0.0
    size: int = 64
    fov_deg: float = 24.0
    distance: float = 3.5

    def camera(self) -> Camera:
        """The pinhole looking at the object's centre ``(0, -0.5, 0)``, principal point at the image centre."""
        c = np.array([0.0, -0.5, 0.0])
        ce, se = math.cos(self.depression), math.sin(self.depression)
        forward = np.array([ce * math.sin(self.azimuth), se, ce * math.cos(self.azimuth)])
        K = intrinsics_from_fov(math.radians(self.fov_deg), self.size, self.size)
        return Camera(K, self.size, self.size, c - self.distance * forward, self.azimuth, -self.depression, self.roll)

    def base_pixel(self) -> np.ndarray:
        """Pixel ``(x, y)`` of the object's foot point (the plane's origin), where it meets the photo's probe pixel."""
        return np.asarray(self.camera().project(np.zeros(3)), dtype=np.float64)


def relight_view(
    pixel: Any,
    K: np.ndarray,
    pitch: float,
    roll: float,
    *,
    size: int = 64,
    min_depression_deg: float = 8.0,
    max_depression_deg: float = 45.0,
) -> RelightView:
    """The view of the photo's probe pixel ``(x, y)`` (intrinsics ``K``, camera pitch and roll in radians).

    The pixel's ray, turned into the panorama frame by ``R(0, pitch, roll)``, gives the azimuth and the
    depression (clamped to ``[min, max]_depression_deg``).
    """
    from solidkit.envmap.coords import rotation_from_ypr

    x, y = float(pixel[0]), float(pixel[1])
    v = np.linalg.inv(np.asarray(K, dtype=np.float64)) @ np.array([x, y, 1.0])
    d = np.asarray(rotation_from_ypr(0.0, pitch, roll)) @ (v / np.linalg.norm(v))
    az, el = angles_from_direction(d)
    dep = min(max(-float(el), math.radians(min_depression_deg)), math.radians(max_depression_deg))
    return RelightView(float(az), dep, float(roll), size=int(size))


# ------------------------------------------------------------------------------------------ geometry


def _ellipsoid(centre: Any, radii: Any, rotation: np.ndarray | None = None, n: int = 24) -> tuple[np.ndarray, ...]:
    """UV ellipsoid: vertices ``(V, 3)``, normals ``(V, 3)``, faces ``(F, 3)`` (outward winding)."""
    th = np.linspace(0.0, math.pi, n // 2 + 1)
    ph = np.linspace(0.0, 2 * math.pi, n + 1)[:-1]
    t, p = np.meshgrid(th, ph, indexing="ij")
    unit = np.stack([np.sin(t) * np.cos(p), -np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    r = np.asarray(radii, dtype=np.float64)
    R = np.eye(3) if rotation is None else np.asarray(rotation)
    verts = (unit * r) @ R.T + np.asarray(centre, dtype=np.float64)
    normals = (unit / r) @ R.T
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    faces = []
    rows, cols = len(th), len(ph)
    for i in range(rows - 1):
        for j in range(cols):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            c, d = a + cols, b + cols
            faces += [(a, c, b), (b, c, d)]
    f = np.asarray(faces, dtype=np.int64)
    tri = verts[f]
    outward = np.sum(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) * normals[f].mean(axis=1), axis=1) < 0
    f[outward] = f[outward][:, [0, 2, 1]]
    return verts, normals, f


def _merge(parts: list[tuple[np.ndarray, ...]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    verts, normals, faces, base = [], [], [], 0
    for v, nrm, f in parts:
        verts.append(v)
        normals.append(nrm)
        faces.append(f + base)
        base += len(v)
    return np.concatenate(verts), np.concatenate(normals), np.concatenate(faces)


def object_mesh(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices ``(V, 3)``, vertex normals ``(V, 3)`` and faces ``(F, 3)`` of an object of :data:`OBJECTS`,
    in its own frame (y down, standing on ``y = 0``, about one unit tall, facing +z)."""
    if name in ("diffuse_sphere", "glossy_sphere"):
        return _merge([_ellipsoid((0.0, -0.5, 0.0), (0.5, 0.5, 0.5), n=48)])
    if name == "bunny":
        tilt = lambda a: np.asarray([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])  # noqa: E731
        splay = lambda a: np.asarray([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])  # noqa: E731
        return _merge(
            [
                _ellipsoid((0.0, -0.32, -0.05), (0.30, 0.31, 0.40), n=32),  # body
                _ellipsoid((0.0, -0.62, 0.30), (0.19, 0.18, 0.20), n=24),  # head
                _ellipsoid((0.0, -0.56, 0.46), (0.07, 0.06, 0.07), n=12),  # snout
                _ellipsoid((0.08, -0.92, 0.22), (0.05, 0.22, 0.08), tilt(-0.35) @ splay(-0.25), n=16),  # ears
                _ellipsoid((-0.08, -0.92, 0.22), (0.05, 0.22, 0.08), tilt(-0.35) @ splay(0.25), n=16),
                _ellipsoid((0.0, -0.30, -0.47), (0.09, 0.09, 0.09), n=12),  # tail
                _ellipsoid((0.14, -0.06, 0.22), (0.08, 0.06, 0.14), n=12),  # front paws
                _ellipsoid((-0.14, -0.06, 0.22), (0.08, 0.06, 0.14), n=12),
            ]
        )
    raise KeyError(f"unknown object {name!r}; one of {', '.join(OBJECTS)}")


def _bsdf(name: str) -> dict[str, Any]:
    if name == "diffuse_sphere":
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}
    if name == "glossy_sphere":
        return {
            "type": "roughplastic",
            "distribution": "ggx",
            "alpha": 0.1,
            "diffuse_reflectance": {"type": "rgb", "value": [0.1, 0.2, 0.6]},
        }
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.75, 0.55, 0.4]}}


def _mesh(mi: Any, name: str, verts: np.ndarray, normals: np.ndarray, faces: np.ndarray, bsdf: Any, label: int) -> Any:
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh(name, len(verts), len(faces), props, has_vertex_normals=True, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = verts.ravel().astype(np.float32)
    params["vertex_normals"] = normals.ravel().astype(np.float32)
    params["faces"] = faces.ravel().astype(np.uint32)
    params.update()
    mesh.add_attribute("face_label", 1, np.full(len(faces), float(label), np.float32))
    return mesh


def _plane(mi: Any) -> Any:
    s = PLANE_HALF_SIZE
    v = np.array([[-s, 0.0, -s], [s, 0.0, -s], [s, 0.0, s], [-s, 0.0, s]])
    n = np.tile([0.0, -1.0, 0.0], (4, 1))
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return _mesh(
        mi, "plane", v, n, f, {"type": "diffuse", "reflectance": {"type": "rgb", "value": [PLANE_ALBEDO] * 3}}, 0
    )


def _object(mi: Any, name: str, view: RelightView) -> Any:
    v, n, f = object_mesh(name)
    if name == "bunny":  # three-quarters to the viewer: its head to the viewer's right
        R = np.asarray(rotation_y(view.azimuth + math.radians(180.0 - 55.0)))
        v, n = v @ R.T, n @ R.T
    return _mesh(mi, name, v, n, f, _bsdf(name), LABEL_OBJECT)


# ------------------------------------------------------------------------------------------ rendering


@dataclass
class ObjectRender:
    """The renders of one object under one probe, linear ``(S, S, 3)`` float32 in the probe's units.

    with_object: plane + object; plane: plane alone; label ``(S, S)`` int: 1 object, 0 plane, -1 background;
    seconds: wall time of the two path-traced renders; view: the :class:`RelightView`.
    """

    name: str
    with_object: np.ndarray
    plane: np.ndarray
    label: np.ndarray
    seconds: float
    view: RelightView

    @property
    def object_mask(self) -> np.ndarray:
        return self.label == LABEL_OBJECT

    @property
    def hit_mask(self) -> np.ndarray:
        """Pixels that see the object or the plane (not the probe itself)."""
        return self.label >= 0


def square_spp(spp: int) -> int:
    """The smallest square number of samples per pixel ``>= spp`` (the multi-jittered sampler's grid)."""
    return max(1, math.ceil(math.sqrt(max(int(spp), 1)))) ** 2


def upper_hemisphere(probe: np.ndarray) -> np.ndarray:
    """The probe ``(H, 2H, 3)`` with its lower half (below the horizon) set to 0, clipped at 0, float32.

    The plane hides those directions from the object and from itself, so the renders are the same; the
    emitter's importance sampling then wastes no sample on them (measured: a quarter less noise on the plane).
    """
    p = np.clip(np.asarray(probe, dtype=np.float32)[..., :3], 0.0, None)
    p[p.shape[0] // 2 :] = 0.0
    return p


def render_objects(
    probe: np.ndarray,
    view: RelightView,
    names: tuple[str, ...] = OBJECTS,
    *,
    spp: int = 16,
    seed: int = 0,
    max_depth: int = 4,
) -> list[ObjectRender]:
    """Path-trace each object of ``names`` (:data:`OBJECTS`) on the plane, and the plane alone once, lit by
    ``probe`` ``(H, 2H, 3)`` (linear, panorama frame; its lower half is not used, :func:`upper_hemisphere`),
    seen from ``view``: ``spp`` samples per pixel (multi-jittered: rounded up to a square,
    :func:`square_spp`), the same ``seed`` for every render (so
    the differences have little noise away from the object). Each render's ``seconds`` is its own render
    plus its share of the plane's."""
    mi = mitsuba()
    spp = square_spp(spp)
    emitter = Lighting(upper_hemisphere(probe)).emitter()
    cam = view.camera()
    sensor = pinhole_sensor(cam, jitter=True, spp=spp, seed=seed, sampler="multijitter")
    t0 = time.perf_counter()
    plane = render_rgb(
        mi.load_dict({"type": "scene", "emitter": emitter, "plane": _plane(mi)}),
        sensor,
        spp,
        max_depth=max_depth,
        seed=seed,
    )
    t_plane = (time.perf_counter() - t0) / max(len(names), 1)
    out = []
    for name in names:
        t0 = time.perf_counter()
        scene = mi.load_dict(
            {"type": "scene", "emitter": emitter, "plane": _plane(mi), "object": _object(mi, name, view)}
        )
        img = render_rgb(scene, sensor, spp, max_depth=max_depth, seed=seed)
        seconds = time.perf_counter() - t0 + t_plane
        out.append(ObjectRender(name, img, plane, _labels(name, view), seconds, view))
    return out


@functools.lru_cache(maxsize=256)
def _labels(name: str, view: RelightView) -> np.ndarray:
    """Object / plane / background label of every pixel (one ray through each pixel centre)."""
    mi = mitsuba()
    scene = mi.load_dict({"type": "scene", "plane": _plane(mi), "object": _object(mi, name, view)})
    sensor = pinhole_sensor(view.camera(), jitter=False, spp=1)
    raw = np.array(mi.render(scene, sensor=sensor, integrator=integrator("sk_buffers", shadows=False), spp=1))
    lab = raw[..., raw.shape[-1] - len(BUFFER_AOVS) + BUFFER_AOVS.index("label")]
    out = np.where(lab > -0.5, np.round(lab), -1).astype(np.int32)
    out.flags.writeable = False
    return out


def composite(
    photo_linear: np.ndarray, render: ObjectRender, pixel: Any, scale: float | None = None, patch: int = 5
) -> tuple[np.ndarray, float]:
    """Differential rendering of ``render`` into ``photo_linear`` ``(H, W, 3)`` (linear) at the probe ``pixel``.

    The render's foot point lands on ``pixel``. The real ground there is measured in a ``patch x patch``
    window of the photo, the virtual one in the same window of the plane-alone render around the foot point
    (channel medians). ``scale`` (render units -> photo units; default: the ratio of their luminances)
    multiplies the object: its pixels take ``scale * with_object``. Elsewhere the photo gets the difference
    ``with_object - plane`` (the object's shadow and bounce light) added, scaled per channel by the real over
    the virtual ground (the plane's albedo estimated from the photo, so that a shadow darkens the real
    ground's colour rather than tinting it). Returns the composite (a copy, clipped at 0) and the scale.
    """
    out = np.array(photo_linear, dtype=np.float32, copy=True)
    H, W = out.shape[:2]
    S = render.with_object.shape[0]
    bx, by = render.view.base_pixel()
    px, py = float(pixel[0]), float(pixel[1])
    h = patch // 2
    xi, yi, rx, ry = int(round(px)), int(round(py)), int(round(bx)), int(round(by))
    real = np.median(out[max(0, yi - h) : yi + h + 1, max(0, xi - h) : xi + h + 1].reshape(-1, 3), axis=0)
    virt = np.median(render.plane[max(0, ry - h) : ry + h + 1, max(0, rx - h) : rx + h + 1].reshape(-1, 3), axis=0)
    ground = np.where(virt > 0, real / np.maximum(virt, 1e-20), 0.0).astype(np.float32)
    if scale is None:
        y_virt = float(luminance(virt[None, None])[0, 0])
        scale = float(luminance(real[None, None])[0, 0]) / y_virt if y_virt > 0 else 1.0
    ox, oy = int(round(px - bx)), int(round(py - by))  # photo pixel of the render's (0, 0)
    x0, y0, x1, y1 = max(0, ox), max(0, oy), min(W, ox + S), min(H, oy + S)
    if x1 <= x0 or y1 <= y0:
        return out, scale
    sl = (slice(y0 - oy, y1 - oy), slice(x0 - ox, x1 - ox))
    obj = render.object_mask[sl][..., None]
    diff = ground * (render.with_object[sl] - render.plane[sl])
    region = out[y0:y1, x0:x1]
    out[y0:y1, x0:x1] = np.where(obj, scale * render.with_object[sl], region + diff)
    return np.clip(out, 0.0, None), scale


def renderer_name() -> str:
    """The Mitsuba variant the renders use (``llvm_ad_rgb``, ``scalar_rgb``...)."""
    return variant()
