"""Procedural, seeded city blocks (in place of Blender SceneCity) and their Mitsuba scenes.

World frame (the *scene frame*): gravity-aligned and laid out like the panorama frame of
docs/conventions.md: **x right/east, y down (along gravity), z forward/north**, metres. The
ground is the plane ``y = 0``; heights are negative ``y``. A camera with yaw ``psi`` has its
panorama frame ``R_y(psi)`` in this frame, so every direction and rotation uses
:mod:`solidkit.envmap` directly. Only the Mitsuba environment emitter needs a change of axes
(Mitsuba's envmap has +y up): see :mod:`solidkit.synth.lighting`.

A block is a street along z (asphalt road, raised sidewalks with curbs, lane markings),
optionally crossed by a second street along x, lined with buildings of varied footprint,
height and facade material, closed at both ends by backdrop buildings, and furnished with
trees (trunk + low-poly canopy), lamp posts, benches, bins, bollards, signs and parked cars.
Every part has an object *label* (instance id, stored as the mesh attribute ``face_label``)
and a *category* (:data:`CATEGORIES`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

import numpy as np

from solidkit.synth.materials import FACADE, MATERIALS, materials_of, texture
from solidkit.synth.mitsuba_variant import mitsuba

__all__ = ["CATEGORIES", "Part", "CityBlock", "box", "quad", "blob", "city_block", "to_mitsuba"]

CATEGORIES = ("road", "sidewalk", "building", "tree", "lamp", "bench", "bin", "bollard", "sign", "car", "marking")


@dataclass
class Part:
    """One mesh: vertices ``(N, 3)`` and uvs ``(N, 2)`` float, faces ``(M, 3)`` int, outward winding."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    material: str
    category: str
    label: int = -1
    group: int = -1


@dataclass
class CityBlock:
    """A procedural city block: parts, walkable floor rectangles and obstacle footprints.

    walkable: ``(x0, x1, z0, z1, floor_y)`` rectangles where cameras may stand;
    obstacles: ``(x0, x1, z0, z1)`` footprints cameras must avoid.
    """

    seed: int
    parts: list[Part] = field(default_factory=list)
    walkable: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    obstacles: list[tuple[float, float, float, float]] = field(default_factory=list)
    _group: int | None = None

    def add(self, part: Part) -> int:
        """Append a part; its label is its index, its group the open object's (else its own label)."""
        part.label = len(self.parts)
        part.group = self._group if self._group is not None else part.label
        self.parts.append(part)
        return part.label

    def begin_object(self) -> None:
        """The next parts (until :meth:`end_object`) form one object (e.g. a car's body and wheels)."""
        self._group = len(self.parts)

    def end_object(self) -> None:
        self._group = None

    def group_of(self, labels: np.ndarray) -> np.ndarray:
        """Object (group) id of part labels; -1 stays -1."""
        table = np.array([p.group for p in self.parts] + [-1])
        lab = np.asarray(labels).astype(np.int64)
        return np.where(lab >= 0, table[np.clip(lab, 0, len(self.parts))], -1)

    def category_of(self, labels: np.ndarray) -> np.ndarray:
        """Category index (into :data:`CATEGORIES`) of object labels; -1 (no hit) stays -1."""
        table = np.array([CATEGORIES.index(p.category) for p in self.parts] + [-1])
        lab = np.asarray(labels).astype(np.int64)
        return np.where(lab >= 0, table[np.clip(lab, 0, len(self.parts))], -1)


def _orient_outward(v: np.ndarray, f: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Flip triangles whose normal points toward ``centre`` (convex parts)."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    c = v[f].mean(axis=1) - centre
    flip = np.sum(n * c, axis=1) < 0
    f = f.copy()
    f[flip] = f[flip][:, [0, 2, 1]]
    return f


def box(lo: Any, hi: Any, material: str, category: str, *, yaw: float = 0.0, tile: float | None = None) -> Part:
    """Axis-aligned box ``lo..hi`` (scene frame, metres), optionally turned by ``yaw`` about the vertical.

    UVs are in tiles of ``tile`` metres (default: the material's ``tile_m``): on the vertical
    faces u runs horizontally and v downward from the top, so facades' window rows align with
    floors counted from the roof line.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    tile = tile or MATERIALS[material].tile_m
    verts: list[np.ndarray] = []
    uvs, faces = [], []
    # each face: (axis, sign) with in-plane axes (u_axis, v_axis)
    for axis, sign in [(0, -1), (0, 1), (2, -1), (2, 1), (1, -1), (1, 1)]:
        ua, va = {0: (2, 1), 2: (0, 1), 1: (0, 2)}[axis]
        c = hi[axis] if sign > 0 else lo[axis]
        base = len(verts)
        for a, b in [(0, 0), (1, 0), (1, 1), (0, 1)]:
            p = np.empty(3)
            p[axis] = c
            p[ua] = lo[ua] if a == 0 else hi[ua]
            p[va] = lo[va] if b == 0 else hi[va]
            verts.append(p)
            uvs.append((p[ua] / tile, (p[va] - lo[va]) / tile))
        faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    v = np.array(verts)
    centre = 0.5 * (lo + hi)
    f = _orient_outward(v, np.array(faces), centre)
    if yaw:
        c, s = np.cos(yaw), np.sin(yaw)
        rel = v - centre
        v = centre + np.stack([c * rel[:, 0] + s * rel[:, 2], rel[:, 1], -s * rel[:, 0] + c * rel[:, 2]], axis=1)
    return Part(v.astype(np.float32), f.astype(np.uint32), np.array(uvs, np.float32), material, category)


def quad(x0: float, x1: float, z0: float, z1: float, y: float, material: str, category: str) -> Part:
    """Horizontal rectangle at height ``y`` facing up (normal ``-y``)."""
    tile = MATERIALS[material].tile_m
    v = np.array([[x0, y, z0], [x1, y, z0], [x1, y, z1], [x0, y, z1]], float)
    f = _orient_outward(v, np.array([[0, 1, 2], [0, 2, 3]]), np.array([0.5 * (x0 + x1), y + 1.0, 0.5 * (z0 + z1)]))
    return Part(v.astype(np.float32), f.astype(np.uint32), (v[:, [0, 2]] / tile).astype(np.float32), material, category)


def blob(centre: Any, radii: Any, material: str, category: str) -> Part:
    """Low-poly ellipsoid (subdivided icosahedron, 80 faces), e.g. a tree canopy."""
    t = (1 + 5**0.5) / 2
    v = [
        (-1, t, 0),
        (1, t, 0),
        (-1, -t, 0),
        (1, -t, 0),
        (0, -1, t),
        (0, 1, t),
        (0, -1, -t),
        (0, 1, -t),
        (t, 0, -1),
        (t, 0, 1),
        (-t, 0, -1),
        (-t, 0, 1),
    ]
    f = [
        (0, 11, 5),
        (0, 5, 1),
        (0, 1, 7),
        (0, 7, 10),
        (0, 10, 11),
        (1, 5, 9),
        (5, 11, 4),
        (11, 10, 2),
        (10, 7, 6),
        (7, 1, 8),
        (3, 9, 4),
        (3, 4, 2),
        (3, 2, 6),
        (3, 6, 8),
        (3, 8, 9),
        (4, 9, 5),
        (2, 4, 11),
        (6, 2, 10),
        (8, 6, 7),
        (9, 8, 1),
    ]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = []
    cache: dict[tuple[int, int], int] = {}

    def mid(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in cache:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            cache[key] = len(verts) - 1
        return cache[key]

    for a, b, c in f:
        ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
        faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
    unit = np.array(verts)
    pos = np.asarray(centre, float) + unit * np.asarray(radii, float)
    fa = _orient_outward(pos, np.array(faces), np.asarray(centre, float))
    tile = MATERIALS[material].tile_m
    rx, ry = float(np.asarray(radii)[0]), float(np.asarray(radii)[1])
    uv = np.stack([np.arctan2(unit[:, 0], unit[:, 2]) * rx / tile, unit[:, 1] * ry / tile], 1)
    return Part(pos.astype(np.float32), fa.astype(np.uint32), uv.astype(np.float32), material, category)


def _pick(rng: np.random.Generator, names: list[str]) -> str:
    return names[int(rng.integers(len(names)))]


def city_block(seed: int, *, length: float = 60.0) -> CityBlock:
    """Generate the city block of ``seed`` (deterministic).

    A street along z over ``[-length, length]`` metres; cameras may stand on its sidewalks and
    road within ``|z| < length / 3``.
    """
    rng = np.random.default_rng([seed, 0x5017D])
    blk = CityBlock(seed=seed)
    hw = float(rng.uniform(3.0, 6.5))  # road half width
    sw = float(rng.uniform(2.0, 4.5))  # sidewalk width
    curb = 0.15
    cross = rng.random() < 0.5
    cz, chw = float(rng.uniform(-length / 4, length / 4)), float(rng.uniform(3.0, 5.5))
    road_mat = _pick(rng, materials_of("asphalt"))
    walk_mat = _pick(rng, materials_of("paving") + materials_of("slab"))
    blk.add(quad(-400, 400, -400, 400, 0.0, road_mat, "road"))
    L = length

    def z_segments(z0: float, z1: float) -> list[tuple[float, float]]:
        if not cross:
            return [(z0, z1)]
        return [(z0, cz - chw - sw), (cz + chw + sw, z1)]

    # sidewalks (with curbs) and lane markings
    for side in (-1, 1):
        x_in, x_out = side * hw, side * (hw + sw)
        xa, xb = min(x_in, x_out), max(x_in, x_out)
        for za, zb in z_segments(-L, L):
            blk.add(box((xa, -curb, za), (xb, 0.0, zb), walk_mat, "sidewalk"))
            z0, z1 = max(za, -L / 3), min(zb, L / 3)
            if z1 > z0 + 0.5:
                blk.walkable.append((xa + 0.3, xb - 0.3, z0, z1, -curb))
    blk.walkable.append((-hw + 0.5, hw - 0.5, -L / 3, L / 3, 0.0))
    dash = float(rng.uniform(2.0, 4.0))
    for z in np.arange(-L, L, 2 * dash):
        if cross and abs(z - cz) < chw + sw:
            continue
        blk.add(quad(-0.08, 0.08, z, z + dash, -0.005, "marking_white", "marking"))
    if cross:
        for side in (-1, 1):
            for xa, xb in ((-L, -hw - sw), (hw + sw, L)):
                za, zb = sorted((cz + side * chw, cz + side * (chw + sw)))
                blk.add(box((xa, -curb, za), (xb, 0.0, zb), walk_mat, "sidewalk"))

    # buildings along both sides, and backdrops closing the street
    def building(x0: float, x1: float, z0: float, z1: float) -> None:
        floors = int(rng.integers(2, 14)) if rng.random() < 0.85 else int(rng.integers(14, 30))
        height = floors * 3.2
        mat = _pick(rng, FACADE)
        blk.begin_object()
        blk.add(box((x0, -height, z0), (x1, 0.0, z1), mat, "building"))
        if rng.random() < 0.35:  # a setback upper part or rooftop volume
            inset = float(rng.uniform(1.0, 3.0))
            h2 = float(rng.uniform(3.0, 10.0))
            if x1 - x0 > 2 * inset + 1 and z1 - z0 > 2 * inset + 1:
                blk.add(box((x0 + inset, -height - h2, z0 + inset), (x1 - inset, -height, z1 - inset), mat, "building"))
        blk.end_object()

    for side in (-1, 1):
        z = -L - 10.0
        while z < L + 10.0:
            width = float(rng.uniform(6.0, 22.0))
            gap = float(rng.uniform(0.0, 3.0)) if rng.random() < 0.4 else 0.0
            z0, z1 = z + gap, min(z + gap + width, L + 10.0)
            z = z1
            if cross and z1 > cz - chw - sw and z0 < cz + chw + sw:
                continue
            setback = float(rng.uniform(0.0, 1.5))
            depth = float(rng.uniform(8.0, 20.0))
            x_front = hw + sw + setback
            xa, xb = sorted((side * x_front, side * (x_front + depth)))
            building(xa, xb, z0, z1)
    for end in (-1, 1):  # backdrops closing the street
        zf = end * (L + 10.0 + float(rng.uniform(0, 15)))
        za, zb = sorted((zf, zf + end * float(rng.uniform(10, 20))))
        building(-(hw + sw + 25.0), hw + sw + 25.0, za, zb)
    if cross:
        for end in (-1, 1):
            xf = end * (L + 5.0)
            xa, xb = sorted((xf, xf + end * 15.0))
            building(xa, xb, cz - chw - sw - 10, cz + chw + sw + 10)

    # street furniture
    def obstacle(x0: float, x1: float, z0: float, z1: float, margin: float = 1.2) -> None:
        blk.obstacles.append((x0 - margin, x1 + margin, z0 - margin, z1 + margin))

    def on_cross(z: float, pad: float = 1.0) -> bool:
        return bool(cross and abs(z - cz) < chw + sw + pad)

    for side in (-1, 1):
        fy = -curb
        z = -L + float(rng.uniform(0, 6))
        spacing = float(rng.uniform(6.0, 12.0))
        foliage, bark = _pick(rng, materials_of("foliage")), _pick(rng, materials_of("bark"))
        while z < L and rng.random() < 0.85:
            if not on_cross(z):
                x = side * (hw + 0.9)
                th = float(rng.uniform(2.0, 3.5))
                blk.begin_object()
                blk.add(box((x - 0.15, fy - th, z - 0.15), (x + 0.15, fy, z + 0.15), bark, "tree"))
                r = float(rng.uniform(1.3, 2.6))
                blk.add(blob((x, fy - th - 0.7 * r, z), (r, 0.9 * r, r), foliage, "tree"))
                blk.end_object()
                obstacle(x - 0.15, x + 0.15, z - 0.15, z + 0.15)
            z += spacing * float(rng.uniform(0.8, 1.2))
        pole = _pick(rng, materials_of("metal"))
        z = -L + float(rng.uniform(0, 10))
        while z < L:
            if not on_cross(z):
                x = side * (hw + 0.35)
                h = float(rng.uniform(5.0, 8.0))
                blk.begin_object()
                blk.add(box((x - 0.07, fy - h, z - 0.07), (x + 0.07, fy, z + 0.07), pole, "lamp"))
                blk.add(
                    box(
                        (x - side * 1.2 - 0.15, fy - h - 0.15, z - 0.2),
                        (x + 0.15, fy - h + 0.05, z + 0.2),
                        pole,
                        "lamp",
                    )
                )
                blk.end_object()
                obstacle(x - 0.07, x + 0.07, z - 0.07, z + 0.07)
            z += float(rng.uniform(15.0, 25.0))
        for _ in range(int(rng.integers(1, 5))):
            z = float(rng.uniform(-L / 2, L / 2))
            if on_cross(z, 3.0):
                continue
            x = side * (hw + sw - 0.7)
            kind = rng.random()
            if kind < 0.4:  # bench
                wood = "woodbench_natural"
                blk.begin_object()
                blk.add(box((x - 0.25, fy - 0.45, z - 0.9), (x + 0.25, fy - 0.4, z + 0.9), wood, "bench"))
                blk.add(box((x + side * 0.2, fy - 0.9, z - 0.9), (x + side * 0.25, fy - 0.45, z + 0.9), wood, "bench"))
                for dz in (-0.8, 0.8):
                    blk.add(box((x - 0.2, fy - 0.4, z + dz - 0.04), (x + 0.2, fy, z + dz + 0.04), pole, "bench"))
                blk.end_object()
                obstacle(x - 0.25, x + 0.25, z - 0.9, z + 0.9)
            elif kind < 0.7:  # bin
                blk.add(
                    box(
                        (x - 0.3, fy - 0.9, z - 0.3), (x + 0.3, fy, z + 0.3), _pick(rng, materials_of("plastic")), "bin"
                    )
                )
                obstacle(x - 0.3, x + 0.3, z - 0.3, z + 0.3)
            else:  # sign
                blk.begin_object()
                blk.add(box((x - 0.04, fy - 2.6, z - 0.04), (x + 0.04, fy, z + 0.04), "metal_galvanized", "sign"))
                plate = _pick(rng, materials_of("plastic"))
                blk.add(box((x - 0.03, fy - 2.8, z - 0.35), (x + 0.03, fy - 2.1, z + 0.35), plate, "sign"))
                blk.end_object()
                obstacle(x - 0.04, x + 0.04, z - 0.04, z + 0.04)
        for _ in range(int(rng.integers(0, 4))):  # bollards near the curb
            z = float(rng.uniform(-L / 3, L / 3))
            if on_cross(z):
                continue
            x = side * (hw + 0.25)
            blk.add(
                box((x - 0.1, fy - 0.9, z - 0.1), (x + 0.1, fy, z + 0.1), _pick(rng, materials_of("metal")), "bollard")
            )
            obstacle(x - 0.1, x + 0.1, z - 0.1, z + 0.1)
        # parked cars along the curb
        z = -L + float(rng.uniform(0, 8))
        while z < L:
            if rng.random() < 0.55 and not on_cross(z, 3.0):
                paint = _pick(rng, materials_of("carpaint"))
                x = side * (hw - 1.1)
                ln, wd = float(rng.uniform(3.8, 4.8)), float(rng.uniform(1.7, 1.9))
                blk.begin_object()
                blk.add(box((x - wd / 2, -1.0, z), (x + wd / 2, -0.3, z + ln), paint, "car"))
                blk.add(
                    box((x - wd / 2 + 0.1, -1.5, z + 0.25 * ln), (x + wd / 2 - 0.1, -1.0, z + 0.75 * ln), paint, "car")
                )
                for dz in (0.6, ln - 0.6):
                    blk.add(
                        box((x - wd / 2, -0.6, z + dz - 0.3), (x + wd / 2, 0.0, z + dz + 0.3), "rubber_black", "car")
                    )
                blk.end_object()
                obstacle(x - wd / 2, x + wd / 2, z, z + ln, margin=1.5)
            z += float(rng.uniform(5.0, 9.0))
    return blk


def _bsdf(mi: ModuleType, name: str, rng: np.random.Generator, *, white: bool = False, tex_size: int = 64) -> Any:
    mat = MATERIALS[name]
    if white:
        return mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}})
    albedo, rough = texture(mat, rng, tex_size)
    common = {"type": "bitmap", "raw": True, "filter_type": "bilinear", "wrap_mode": "repeat"}
    tex = {**common, "bitmap": mi.Bitmap(albedo)}
    rtex = {**common, "bitmap": mi.Bitmap(rough[..., None])}
    return mi.load_dict(
        {"type": "principled", "base_color": tex, "roughness": rtex, "metallic": float(mat.metallic), "specular": 0.5}
    )


def _mesh(mi: ModuleType, part: Part, bsdf: Any, name: str) -> Any:
    props = mi.Properties()
    props["bsdf"] = bsdf
    mesh = mi.Mesh(
        name, len(part.vertices), len(part.faces), props, has_vertex_normals=False, has_vertex_texcoords=True
    )
    params = mi.traverse(mesh)
    params["vertex_positions"] = part.vertices.ravel().astype(np.float32)
    params["faces"] = part.faces.ravel().astype(np.uint32)
    params["vertex_texcoords"] = part.uvs.ravel().astype(np.float32)
    params.update()
    mesh.add_attribute("face_label", 1, np.full(len(part.faces), float(part.label), np.float32))
    return mesh


def to_mitsuba(
    block: CityBlock | None,
    emitter: dict[str, Any] | None,
    *,
    white: bool = False,
    tex_size: int = 64,
    extra: dict[str, Any] | None = None,
) -> Any:
    """A Mitsuba scene of ``block`` (None: no geometry) lit by ``emitter`` (a plugin dict).

    Textures are drawn from a generator seeded by the block's seed, so the same block always
    gets the same textures. ``white=True`` makes every surface a white (0.8) Lambertian.
    """
    mi = mitsuba()
    desc: dict[str, Any] = {"type": "scene"}
    if emitter is not None:
        desc["emitter"] = emitter
    if block is not None:
        rng = np.random.default_rng([block.seed, 0x7E47])
        bsdfs: dict[str, Any] = {}
        for part in block.parts:
            if part.material not in bsdfs:
                bsdfs[part.material] = _bsdf(mi, part.material, rng, white=white, tex_size=tex_size)
            desc[f"part_{part.label:04d}"] = _mesh(mi, part, bsdfs[part.material], f"part_{part.label:04d}")
    desc.update(extra or {})
    return mi.load_dict(desc)
