"""A library of 84 material categories with seeded procedural textures (in place of SceneCity's 80).

Each category has a linear diffuse albedo (sRGB colour decoded with
:func:`solidkit.envmap.srgb_decode`), a roughness, a metallic value and a texture pattern.
:func:`texture` renders one tileable texture tile (albedo ``(T, T, 3)`` linear, roughness
``(T, T)``); textures are periodic by construction (FFT noise, integer pattern repeats), so they
tile seamlessly with ``wrap_mode = repeat``. Facade categories get a window grid (one window per
bay of ``tile_m`` metres and floor), dark and glossy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solidkit.envmap import srgb_decode

__all__ = ["Material", "MATERIALS", "FACADE", "GROUND", "texture", "materials_of"]


@dataclass(frozen=True)
class Material:
    """One material category.

    name: unique id; family: pattern family; albedo: linear RGB in [0, 1]; roughness in (0, 1];
    metallic in [0, 1]; tile_m: size in metres of one texture tile; use: 'facade', 'ground',
    'object'; windows: facade with a window grid.
    """

    name: str
    family: str
    albedo: tuple[float, float, float]
    roughness: float
    metallic: float
    tile_m: float
    use: str
    windows: bool = False


def _hex(c: str) -> tuple[float, float, float]:
    rgb = np.array([int(c[i : i + 2], 16) for i in (0, 2, 4)], dtype=np.float64) / 255.0
    return tuple(float(x) for x in srgb_decode(rgb))  # type: ignore[return-value]


_SPEC: list[tuple[str, str, float, float, float, bool, dict[str, str]]] = [
    # family, use, roughness, metallic, tile_m, windows, {variant: sRGB hex}
    (
        "brick",
        "facade",
        0.85,
        0.0,
        3.2,
        True,
        {
            "red": "9a4a3a",
            "darkred": "6e3328",
            "brown": "7a5840",
            "yellow": "c8a96e",
            "whitewashed": "d8d2c8",
            "grey": "8a8580",
            "orange": "b8683f",
            "purple": "6a4a4a",
        },
    ),
    (
        "plaster",
        "facade",
        0.9,
        0.0,
        3.2,
        True,
        {
            "white": "e8e4da",
            "cream": "e6d8b0",
            "ochre": "c99a4e",
            "salmon": "d99a80",
            "paleblue": "a8bccc",
            "palegreen": "b4c4a0",
            "grey": "a8a8a4",
            "terracotta": "b06a48",
            "pink": "d8a8a8",
            "beige": "cdbb9a",
        },
    ),
    (
        "concrete",
        "facade",
        0.8,
        0.0,
        3.2,
        True,
        {"light": "b8b6b0", "mid": "8e8c88", "dark": "5e5c5a", "warm": "a89c8a", "cool": "8c949a", "stained": "7c786e"},
    ),
    (
        "stone",
        "facade",
        0.75,
        0.0,
        3.2,
        True,
        {
            "sandstone": "c8aa80",
            "limestone": "d6ceb8",
            "granitegrey": "7e7e7c",
            "granitered": "9a6a5e",
            "slate": "4e5258",
            "travertine": "c8b89a",
        },
    ),
    (
        "panel",
        "facade",
        0.4,
        0.6,
        3.2,
        True,
        {
            "white": "d8d8d8",
            "grey": "909498",
            "darkgrey": "4a4c50",
            "blue": "4a6a8a",
            "red": "8a3a32",
            "green": "4a6a50",
        },
    ),
    (
        "curtainglass",
        "facade",
        0.12,
        0.2,
        3.2,
        True,
        {"blue": "3a5068", "green": "3e5a50", "grey": "4a4e52", "bronze": "5a4a3a", "silver": "8a9098"},
    ),
    ("woodclad", "facade", 0.7, 0.0, 3.2, True, {"light": "b89a70", "dark": "6a4a30", "cedar": "9a5a3a"}),
    (
        "tilefacade",
        "facade",
        0.3,
        0.0,
        3.2,
        True,
        {"white": "e0e0dc", "beige": "d0c0a0", "blue": "6a8aaa", "green": "7a9a80"},
    ),
    ("asphalt", "ground", 0.9, 0.0, 4.0, False, {"new": "3a3a3c", "old": "5a5a58", "patched": "4a4846"}),
    (
        "paving",
        "ground",
        0.8,
        0.0,
        2.0,
        False,
        {"grey": "9a9894", "red": "9a6a5a", "beige": "bcae94", "cobble": "6e6a64"},
    ),
    ("slab", "ground", 0.85, 0.0, 3.0, False, {"light": "b0aea8", "dark": "7e7c78"}),
    ("grass", "ground", 0.95, 0.0, 2.0, False, {"green": "5a7a38", "dry": "8a8a50"}),
    ("dirt", "ground", 0.95, 0.0, 2.0, False, {"brown": "7a6048"}),
    (
        "foliage",
        "object",
        0.8,
        0.0,
        1.5,
        False,
        {"green": "3e6a2a", "dark": "2a4a22", "yellowgreen": "6a8a30", "autumn": "a06a2a"},
    ),
    ("bark", "object", 0.9, 0.0, 1.0, False, {"brown": "5a4432", "grey": "6a6660"}),
    (
        "metal",
        "object",
        0.45,
        0.8,
        1.0,
        False,
        {"paintedgreen": "2e4a3a", "black": "262626", "grey": "7a7e82", "galvanized": "a0a4a8", "rust": "7a4a30"},
    ),
    (
        "carpaint",
        "object",
        0.2,
        0.3,
        2.0,
        False,
        {
            "white": "e0e0e0",
            "black": "1e1e20",
            "silver": "a0a4a8",
            "red": "9a1e1e",
            "blue": "1e3a7a",
            "darkgreen": "1e4a32",
            "yellow": "d8b020",
        },
    ),
    ("plastic", "object", 0.5, 0.0, 1.0, False, {"green": "2e6a3a", "grey": "6a6a6a", "orange": "d06a20"}),
    ("woodbench", "object", 0.7, 0.0, 1.0, False, {"natural": "8a6440"}),
    ("rubber", "object", 0.9, 0.0, 1.0, False, {"black": "1a1a1a"}),
    ("marking", "ground", 0.6, 0.0, 1.0, False, {"white": "d8d8d0"}),
]

MATERIALS: dict[str, Material] = {}
for _fam, _use, _rough, _metal, _tile, _win, _variants in _SPEC:
    for _var, _col in _variants.items():
        _m = Material(f"{_fam}_{_var}", _fam, _hex(_col), _rough, _metal, _tile, _use, _win)
        MATERIALS[_m.name] = _m
FACADE = sorted(n for n, m in MATERIALS.items() if m.use == "facade")
GROUND = sorted(n for n, m in MATERIALS.items() if m.use == "ground")


def materials_of(family: str) -> list[str]:
    """Names of the categories of one family (e.g. ``"carpaint"``)."""
    return sorted(n for n, m in MATERIALS.items() if m.family == family)


def _fft_noise(rng: np.random.Generator, size: int, beta: float = 2.0) -> np.ndarray:
    """Periodic 1/f^beta noise, zero mean, unit std, ``(size, size)``."""
    f = np.fft.fftfreq(size)
    k = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2)
    k[0, 0] = np.inf
    spec = (rng.standard_normal((size, size)) + 1j * rng.standard_normal((size, size))) / k ** (beta / 2)
    n = np.real(np.fft.ifft2(spec))
    return (n - n.mean()) / (n.std() + 1e-12)


def _grid_lines(size: int, count_x: int, count_y: int, width: float, offset_rows: bool = False) -> np.ndarray:
    """1 on joints of a ``count_x x count_y`` block grid (running bond if ``offset_rows``)."""
    y, x = np.mgrid[0:size, 0:size] + 0.5
    fy = y / size * count_y
    row = np.floor(fy)
    fx = x / size * count_x + (0.5 * (row % 2) if offset_rows else 0.0)
    dx = np.abs(fx - np.round(fx)) * size / count_x
    dy = np.abs(fy - np.round(fy)) * size / count_y
    return ((dx < width) | (dy < width)).astype(np.float64)


def texture(mat: Material, rng: np.random.Generator, size: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """One tileable texture tile of ``mat``: albedo ``(size, size, 3)`` linear float32, roughness ``(size, size)``.

    The tile covers ``mat.tile_m`` metres on a side; pixel rows run downward in the facade.
    """
    base = np.asarray(mat.albedo, dtype=np.float64)
    shade = 1.0 + 0.08 * _fft_noise(rng, size, 2.5)  # large-scale weathering
    fam = mat.family
    joint = None
    if fam == "brick":
        joint = _grid_lines(size, 6, 20, 0.6, offset_rows=True)
        shade = shade * (1.0 + 0.12 * _fft_noise(rng, size, 0.5))
    elif fam in ("stone", "paving", "slab", "tilefacade"):
        n = {"stone": (3, 6), "paving": (6, 6), "slab": (3, 3), "tilefacade": (8, 16)}[fam]
        joint = _grid_lines(size, n[0], n[1], 0.6, offset_rows=fam == "stone")
        shade = shade * (1.0 + 0.06 * _fft_noise(rng, size, 1.0))
    elif fam in ("panel", "curtainglass", "concrete"):
        n = {"panel": (2, 2), "curtainglass": (2, 1), "concrete": (1, 1)}[fam]
        joint = _grid_lines(size, n[0], n[1], 0.8)
    elif fam in ("woodclad", "woodbench", "bark"):
        y = np.arange(size)[:, None] / size
        stripes = np.sin(2 * np.pi * (8 * y + 0.3 * _fft_noise(rng, size, 2.0)))
        shade = shade * (1.0 + 0.1 * stripes)
        if fam == "bark":
            shade = shade.T
    elif fam in ("asphalt", "grass", "foliage", "dirt"):
        shade = shade * (1.0 + 0.18 * _fft_noise(rng, size, 0.8))
    else:
        shade = shade * (1.0 + 0.03 * _fft_noise(rng, size, 1.5))
    albedo = base[None, None, :] * shade[..., None]
    rough = np.full((size, size), mat.roughness)
    if joint is not None:
        albedo = albedo * (1.0 - 0.35 * joint[..., None])
        rough = np.where(joint > 0, 0.95, rough)
    if mat.windows:
        y, x = np.mgrid[0:size, 0:size] + 0.5
        wx = (x > 0.28 * size) & (x < 0.72 * size)
        wy = (y > 0.22 * size) & (y < 0.72 * size)
        frame = ((x > 0.25 * size) & (x < 0.75 * size) & (y > 0.19 * size) & (y < 0.75 * size)) & ~(wx & wy)
        glass = rng.uniform(0.02, 0.08) * np.array([0.9, 1.0, 1.1])
        albedo = np.where((wx & wy)[..., None], glass[None, None, :], albedo)
        albedo = np.where(frame[..., None], 0.6 * albedo + 0.1, albedo)
        rough = np.where(wx & wy, 0.1, rough)  # glossy, not mirror-like: mirror caustics of the sun are fireflies
    return np.clip(albedo, 0.0, 0.95).astype(np.float32), np.clip(rough, 0.02, 1.0).astype(np.float32)
