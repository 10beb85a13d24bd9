"""The dual-fisheye camera model as image formation: lens profile -> remap tables -> per-lens panoramas.

For every pixel of a ``(H, 2H)`` equirect panorama (direction from
:func:`solidkit.envmap.coords.direction_from_coords`, evaluated in row blocks to bound memory)
the direction is taken into the camera frame (``d_cam = R_levelᵀ d_pano``) and projected into
each lens through the profile (:func:`solidkit.camera.lens.project`); :class:`UnwarpMaps` holds
the resulting ``cv2.remap`` tables and the feather weights (:func:`feather_weights`),
:func:`warp_lens` samples one lens, :func:`match_gains` equalises the lenses on their overlap and
:func:`seam_disagreement` measures what is left. Blending, vignetting and file products are
:mod:`solidkit.capture.unwarp`'s; the overlap calibration
(:mod:`solidkit.calibration.overlap`) judges a lens profile by the same pieces.

Remap tables are cached per (profile, input size, output size, orientation): in memory (LRU of
:data:`CACHE_SIZE` entries) and optionally on disk (a ``.tables`` file named by a SHA-256 of the key,
memory-mapped when read, written in the background), as OpenCV fixed-point maps (1/32 px, what
``cv2.remap`` uses internally for bilinear sampling). Two-lens 8-bit unwarping reads
:class:`CutMaps` (the dominant lens everywhere, both lenses on the feather band only).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar, cast

import cv2
import numpy as np

from solidkit.camera.lens import LensProfile, project
from solidkit.camera.raw import is_raw_file, read_raw
from solidkit.envmap.coords import direction_from_coords
from solidkit.envmap.io import imread, read_exr, read_ldr, srgb_decode, srgb_encode
from solidkit.errors import InputError
from solidkit.fsutil import atomic_path

__all__ = [
    "CACHE_SIZE",
    "UnwarpMaps",
    "CutMaps",
    "feather_weights",
    "lens_samples",
    "build_maps",
    "get_maps",
    "build_cut_maps",
    "get_cut_maps",
    "clear_cache",
    "srgb8_luts",
    "encode_srgb8",
    "warp_lens",
    "match_gains",
    "seam_disagreement",
    "read_input",
    "read_linear",
]

CACHE_SIZE = 4
_ROWS = 256
#: Largest spacing (output px) of exactly projected table nodes (:func:`lens_samples`).
MAX_GRID_STEP = 8
#: Largest interpolation error of the remap tables between nodes: half their 1/32-px resolution.
MAP_TOLERANCE_PX = 1 / 64
#: Size bound of an on-disk table cache folder (least recently used files go first).
DISK_CACHE_MAX_BYTES = 2 << 30
_cache: OrderedDict[str, Any] = OrderedDict()  # UnwarpMaps and CutMaps by key
_writing: dict[Path, threading.Thread] = {}  # cache files being written in the background


@dataclass
class UnwarpMaps:
    """Per-lens remap tables for one (profile, input size, output size, orientation).

    ``map1`` ``(L, H, 2H, 2)`` int16 and ``map2`` ``(L, H, 2H)`` uint16: OpenCV's fixed-point
    maps (``cv2.convertMaps(..., CV_16SC2)``; 1/32-px sub-pixel positions, the precision
    ``cv2.remap`` uses internally for bilinear interpolation anyway) of the fisheye pixel
    coordinates; ``weight``: ``(L, H, 2H)`` float32 feather weights summing to 1 where any lens
    sees (0 where a lens does not).
    """

    map1: np.ndarray
    map2: np.ndarray
    weight: np.ndarray
    _derived: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"map1": self.map1, "map2": self.map2, "weight": self.weight}

    def derived(self, name: str, key: Any, build: Callable[[], Any]) -> Any:
        """A value derived from these maps (e.g. vignetting gains), built once per ``key`` and kept with
        them: ``build()`` runs when nothing is kept under ``name`` or it was built for another key."""
        kept = self._derived.get(name)
        if kept is not None and kept[0] == key:
            return kept[1]
        value = build()
        self._derived[name] = (key, value)
        return value

    def band(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Two lenses: ``(lens0_dominant (H, 2H) bool, band flat indices, lens-0 weight there)``."""
        if "band" not in self._derived:
            w0 = self.weight[0]
            idx = np.flatnonzero((w0 > 0) & (self.weight[1] > 0))
            self._derived["band"] = (w0 >= 0.5, idx, w0.reshape(-1)[idx].astype(np.float32))
        return cast(tuple[np.ndarray, np.ndarray, np.ndarray], self._derived["band"])

    @property
    def coverage(self) -> np.ndarray:
        """``(H, 2H)`` bool: some lens sees this output pixel."""
        return cast(np.ndarray, self.weight.sum(axis=0) > 0)

    @property
    def overlap(self) -> np.ndarray:
        """``(H, 2H)`` bool: blended pixels (at least two lenses with weight > 0)."""
        return cast(np.ndarray, (self.weight > 0).sum(axis=0) >= 2)


def feather_weights(margin: np.ndarray, feather_deg: float) -> np.ndarray:
    """Cross-fade weights ``(L, ...)`` from angular margins ``(L, ...)`` (radians); see module doc."""
    L = margin.shape[0]
    f = max(math.radians(feather_deg), 1e-6)
    valid = margin > 0
    m = np.where(valid, margin, -np.inf)
    if L == 1:
        return valid.astype(np.float32)
    w = np.empty_like(margin, dtype=np.float32)
    for i in range(L):
        others = np.max(np.delete(m, i, axis=0), axis=0)
        with np.errstate(invalid="ignore"):  # -inf - -inf where no lens sees: masked below
            diff = np.where(np.isfinite(others), m[i] - others, np.inf)
        w[i] = np.where(valid[i], np.clip(0.5 + diff / (2 * f), 0.0, 1.0), 0.0)
    s = w.sum(axis=0)
    return np.where(s > 0, w / np.where(s > 0, s, 1), 0).astype(np.float32)


def _grid_step(prof: LensProfile, out_height: int) -> int:
    """Spacing (output px) of the exactly projected nodes of the remap tables (see :func:`lens_samples`).

    Bilinear interpolation between nodes ``s`` px apart is off by about ``0.4 s² f''`` px, with
    ``f'' ≈ (π/H)² r'`` the tables' curvature (``r'`` the lenses' px per radian); measured on the
    Theta V at 5792 -> 5376x2688: 0.007 px at ``s = 4``, 0.011 px at ``s = 5`` (the step chosen there). The step is
    the largest, up to :data:`MAX_GRID_STEP`, that keeps it below :data:`MAP_TOLERANCE_PX`; small outputs are exact
    (1).
    """
    px_per_rad = max(lens.max_radius() / math.radians(lens.max_angle_deg) for lens in prof.lenses)
    curvature = (math.pi / out_height) ** 2 * px_per_rad
    return max(1, min(MAX_GRID_STEP, int(math.sqrt(MAP_TOLERANCE_PX / (0.4 * curvature)))))


def lens_samples(
    profile: LensProfile, in_size: tuple[int, int], out_height: int, R_level: Any = None, block_rows: int = _ROWS
) -> Iterator[tuple[int, int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]]:
    """Where each lens sees every pixel of a ``(out_height, 2 out_height)`` panorama, in row blocks.

    Yields ``(r0, r1, [(x, y, margin) per lens])`` for output rows ``r0:r1``: ``x, y`` ``(r1 - r0, 2H)``
    float32 fisheye pixel coordinates (OpenCV convention; unbounded where the lens does not see) and
    ``margin`` = ``max_angle - theta`` (radians; below 0 where the lens does not see the pixel or its
    sample falls outside the frame). The projection (:func:`solidkit.camera.lens.project`) is evaluated
    exactly on nodes every ``s`` output pixels (:func:`_grid_step`; the nodes extend one step beyond
    the panorama: directions are smooth across the seam and the poles) and bilinearly in between
    (``cv2.resize``, whose pixel-centre convention puts node ``k`` at ``(k + 0.5) s``): the map of a
    smooth function, 25x fewer projections at Theta V size, within :data:`MAP_TOLERANCE_PX`.
    """
    grid = _NodeGrid(profile, in_size, out_height, R_level)
    for r0, r1 in grid.blocks(block_rows):
        yield r0, r1, grid.samples(r0, r1)


class _NodeGrid:
    """The projection of :func:`lens_samples` on its node grid, interpolated block by block."""

    def __init__(self, profile: LensProfile, in_size: tuple[int, int], out_height: int, R_level: Any = None):
        self.prof = profile.scaled(*in_size)
        self.R = np.eye(3) if R_level is None else np.asarray(R_level, dtype=np.float64)
        self.H, self.W = out_height, 2 * out_height
        self.in_size = in_size
        w_in, h_in = in_size
        # a lens whose whole image circle lies in the frame never samples outside it where it sees
        self.framed = [
            min(lens.center[0] + 0.5, w_in - 0.5 - lens.center[0], lens.center[1] + 0.5, h_in - 0.5 - lens.center[1])
            >= lens.max_radius()
            for lens in self.prof.lenses
        ]
        self.s = _grid_step(self.prof, self.H)
        self.pad = 1 if self.s > 1 else 0
        if self.s > 1:
            s, pad = self.s, self.pad
            self.nodes = self._project(
                (np.arange(-(-self.H // s) + 2 * pad) - pad + 0.5) * s,
                (np.arange(-(-self.W // s) + 2 * pad) - pad + 0.5) * s,
            )

    def _project(self, ys: np.ndarray, xs: np.ndarray) -> list[list[np.ndarray]]:
        yy, xx = np.meshgrid(ys, xs, indexing="ij")
        d_cam = direction_from_coords(xx, yy, self.H) @ self.R  # row vectors: (R^T d)^T
        planes = []
        for lens in self.prof.lenses:
            x, y, theta = project(lens, d_cam)
            planes.append(
                [
                    x.astype(np.float32),
                    y.astype(np.float32),
                    (math.radians(lens.max_angle_deg) - theta).astype(np.float32),
                ]
            )
        return planes

    def blocks(self, block_rows: int = _ROWS) -> Iterator[tuple[int, int]]:
        block = max(self.s, block_rows // self.s * self.s)
        for r0 in range(0, self.H, block):
            yield r0, min(self.H, r0 + block)

    def slab(self, r0: int, r1: int) -> slice:
        """The node rows whose interpolation covers output rows ``r0:r1`` (``s > 1``)."""
        return slice(r0 // self.s, r0 // self.s + -(-(r1 - r0) // self.s) + 2 * self.pad)

    def interpolate(self, plane: np.ndarray, r0: int, r1: int) -> np.ndarray:
        """A node plane at output rows ``r0:r1`` (bilinear; see :func:`lens_samples`)."""
        s, pad = self.s, self.pad
        p = plane[self.slab(r0, r1)]
        return cv2.resize(p, (p.shape[1] * s, p.shape[0] * s), interpolation=cv2.INTER_LINEAR)[
            pad * s : pad * s + (r1 - r0), pad * s : pad * s + self.W
        ]

    def interpolate_columns(self, plane: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """:meth:`interpolate` at output columns ``c0:c1`` only, from the nodes they need and one more on each side:
        the same values (each pixel is the same bilinear blend of the same four nodes), a fraction of the work."""
        s, pad = self.s, self.pad
        p = plane[self.slab(r0, r1)]
        j0 = max(0, (c0 + pad * s) // s - 2)
        j1 = min(p.shape[1], (c1 - 1 + pad * s) // s + 3)
        q = p[:, j0:j1]
        x0 = c0 + pad * s - j0 * s
        return cv2.resize(q, (q.shape[1] * s, q.shape[0] * s), interpolation=cv2.INTER_LINEAR)[
            pad * s : pad * s + (r1 - r0), x0 : x0 + (c1 - c0)
        ]

    def samples(self, r0: int, r1: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``[(x, y, margin) per lens]`` at output rows ``r0:r1`` (see :func:`lens_samples`)."""
        if self.s == 1:
            planes = self._project(np.arange(r0, r1) + 0.5, np.arange(self.W) + 0.5)
        else:
            planes = [[self.interpolate(p, r0, r1) for p in lens_nodes] for lens_nodes in self.nodes]
        w_in, h_in = self.in_size
        out = []
        for (x, y, m), inframe in zip(planes, self.framed):
            if not inframe:
                outside = (
                    (x < -0.5) | (x > w_in - 0.5) | (y < -0.5) | (y > h_in - 0.5)
                )  # never sample outside the frame
                m = np.where(outside, np.minimum(m, np.float32(-1e-6)), m)
            out.append((x, y, m))
        return out


def build_maps(
    profile: LensProfile, in_size: tuple[int, int], out_height: int, R_level: Any = None, feather_deg: float = 10.0
) -> UnwarpMaps:
    """Remap tables for unwarping a ``in_size = (W, H)`` dual-fisheye image to a ``(out_height, 2 out_height)``
    panorama."""
    H, W, L = out_height, 2 * out_height, len(profile.lenses)
    w_in, h_in = in_size
    map1 = np.empty((L, H, W, 2), np.int16)
    map2 = np.empty((L, H, W), np.uint16)
    weight = np.empty((L, H, W), np.float32)
    for r0, r1, lenses in lens_samples(profile, in_size, out_height, R_level):
        for i, (x, y, _) in enumerate(lenses):  # clipped: where a lens does not see, its coordinates are unbounded
            map1[i, r0:r1], map2[i, r0:r1] = cv2.convertMaps(
                np.clip(x, -2.0, w_in + 1.0), np.clip(y, -2.0, h_in + 1.0), cv2.CV_16SC2
            )
        weight[:, r0:r1] = feather_weights(
            np.stack([m for _, _, m in lenses]), feather_deg
        )  # per pixel: block by block
    return UnwarpMaps(map1, map2, weight)


def _key(profile: LensProfile, in_size: tuple[int, int], out_height: int, R: np.ndarray, feather_deg: float) -> str:
    h = hashlib.sha256()
    h.update(profile.key().encode())
    h.update(repr((tuple(in_size), int(out_height), float(feather_deg))).encode())
    h.update(np.round(np.asarray(R, dtype=np.float64), 12).tobytes())
    return h.hexdigest()[:24]


def clear_cache() -> None:
    """Empty the in-memory remap cache (after finishing the on-disk writes under way)."""
    while _writing:
        _writing.popitem()[1].join()
    _cache.clear()


_ALIGN = 4096


def _save_tables(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` to one file that :func:`_load_tables` memory-maps, atomically (concurrent
    writers of one key each rename a complete file); a cache that cannot be written is only a slower
    next run (a warning). Layout: a JSON index (name -> dtype, shape, offset) padded to 4 KiB, then
    each array's bytes at a 4 KiB-aligned offset."""
    try:
        index: dict[str, list[Any]] = {}
        offset = _ALIGN
        for name, a in arrays.items():
            index[name] = [a.dtype.str, list(a.shape), offset]
            offset += -(-a.nbytes // _ALIGN) * _ALIGN
        head = json.dumps({"format": "solidkit-remap-tables-1", "arrays": index}).encode()
        if len(head) > _ALIGN:
            raise OSError(0, "table index too long")
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path, suffix=".tables") as tmp:
            with open(tmp, "wb") as f:
                f.write(head.ljust(_ALIGN, b" "))
                for name, a in arrays.items():
                    f.seek(index[name][2])
                    f.write(np.ascontiguousarray(a).data)
                f.truncate(offset)
        _evict(path.parent, keep=path)
    except OSError as exc:
        warnings.warn(f"{path}: remap tables not cached ({exc.strerror or exc})", RuntimeWarning, stacklevel=1)


def _evict(folder: Path, keep: Path, max_bytes: int | None = None) -> None:
    """Delete the least recently used table files of ``folder`` beyond :data:`DISK_CACHE_MAX_BYTES` (each
    levelling has its own tables: without a bound the cache would grow by ~150 MB per Theta V capture).
    A file another process has mapped stays readable to it after the unlink."""
    limit = DISK_CACHE_MAX_BYTES if max_bytes is None else max_bytes
    files = []
    for f in folder.glob("*.tables"):
        try:
            st = f.stat()
        except OSError:
            continue
        files.append((st.st_mtime, st.st_size, f))
    total = sum(size for _, size, _ in files)
    for _, size, f in sorted(files):
        if total <= limit:
            break
        if f != keep:
            f.unlink(missing_ok=True)
            total -= size


def _load_tables(path: Path) -> dict[str, np.ndarray]:
    """The arrays of a :func:`_save_tables` file, memory-mapped read-only (pages come straight from
    the page cache: no copy, little memory of this process's own)."""
    with open(path, "rb") as f:
        head = json.loads(f.read(_ALIGN).decode())
    if head.get("format") != "solidkit-remap-tables-1":
        raise ValueError(f"{path}: not a remap table file")
    size = path.stat().st_size
    out = {}
    for name, (dtype, shape, offset) in head["arrays"].items():
        n = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        if offset + n > size:
            raise ValueError(f"{path}: truncated")
        out[name] = (
            np.memmap(path, dtype=np.dtype(dtype), mode="r", offset=offset, shape=tuple(shape))
            if n
            else np.zeros(shape, np.dtype(dtype))
        )
    return out


def _cached(key: str, cache_dir: str | os.PathLike[str] | None, build: Any, load: Any) -> tuple[Any, str]:
    """In-memory LRU, then ``cache_dir/<key>.tables`` (memory-mapped; written atomically in the background:
    concurrent runs are safe), then ``build()``."""
    if key in _cache:
        _cache.move_to_end(key)
        return _cache[key], "memory"
    path = Path(cache_dir) / f"{key}.tables" if cache_dir is not None else None
    maps = None
    source = "built"
    if path in _writing:  # this process is still writing it
        _writing.pop(path).join()
    if path is not None and path.is_file():
        try:
            maps = load(_load_tables(path))
            source = "disk"
            os.utime(path)  # recently used: evicted last
        except (OSError, ValueError, KeyError, UnicodeDecodeError):
            maps = None  # unreadable cache file: rebuild and overwrite
    if maps is None:
        maps = build()
        if path is not None:  # written while the caller goes on with the tables (the interpreter waits for it at exit)
            _writing[path] = threading.Thread(
                target=_save_tables, args=(path, maps.arrays()), name="solidkit-cache-write"
            )
            _writing[path].start()
    _cache[key] = maps
    while len(_cache) > CACHE_SIZE:
        _cache.popitem(last=False)
    return maps, source


def get_maps(
    profile: LensProfile,
    in_size: tuple[int, int],
    out_height: int,
    R_level: Any = None,
    feather_deg: float = 10.0,
    cache_dir: str | os.PathLike[str] | None = None,
) -> tuple[UnwarpMaps, str]:
    """:func:`build_maps` through the in-memory LRU and the optional on-disk cache.

    Returns ``(maps, source)`` with ``source`` one of ``"memory"``, ``"disk"``, ``"built"``.
    """
    R = np.eye(3) if R_level is None else np.asarray(R_level, dtype=np.float64)
    key = _key(profile, in_size, out_height, R, feather_deg)
    return _cached(
        f"unwarp-{key}",
        cache_dir,
        lambda: build_maps(profile, in_size, out_height, R, feather_deg),
        lambda z: UnwarpMaps(z["map1"], z["map2"], z["weight"]),
    )


_BAND_COLS = 4096  # band tables are laid out (rows, 4096): cv2.remap wants both sides below 32767


@dataclass
class CutMaps:
    """Two-lens remap tables for 8-bit unwarping: the dominant lens everywhere, both lenses on the feather band.

    The same geometry and feather weights as :class:`UnwarpMaps`, stored for what a two-lens
    8-bit unwarp reads (:func:`solidkit.capture.unwarp.unwarp_srgb8`): one ``cv2.remap`` of the
    whole frame gives every output pixel its dominant lens' sample (lens 0 where its weight is
    >= 0.5), and only the ``n`` pixels of the band (both weights > 0) are sampled from both lenses
    and blended: 3 bytes a pixel of tables instead of 12 (two lenses' maps and weights).

    ``map1`` ``(H, 2H, 2)`` int16, ``map2`` ``(H, 2H)`` uint16: fixed-point tables of the dominant
    lens (pixels no lens sees point outside the frame: black); ``lead`` ``(H, 2H)`` uint8: 1 where
    lens 0 dominates; ``band`` ``(n,)`` int32 flat output indices, ``band_w0`` ``(n,)`` float32 lens
    0's weight there, laid out ``(rows, 4096)`` (padded with 0); ``band_map1`` ``(2, rows, 4096, 2)`` int16,
    ``band_map2`` ``(2, rows, 4096)`` uint16: each lens' tables for the band pixels in order (padded);
    ``coverage``: fraction of output pixels some lens sees.
    """

    LAYOUT: ClassVar[int] = 2  # in the cache file names: tables of an earlier layout are never read
    map1: np.ndarray
    map2: np.ndarray
    lead: np.ndarray
    band: np.ndarray
    band_w0: np.ndarray
    band_map1: np.ndarray
    band_map2: np.ndarray
    coverage: float

    def arrays(self) -> dict[str, np.ndarray]:
        return {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_arrays(cls, z: Any) -> CutMaps:
        """From :meth:`arrays` (a cache file); ``ValueError`` when the layout is not this one."""
        m = cls(**{f.name: z[f.name] for f in fields(cls) if f.name != "coverage"}, coverage=float(z["coverage"][()]))
        rows = m.band_map2.shape[1] if m.band_map2.ndim == 3 else -1
        if m.map1.shape[:2] != m.lead.shape or m.band_w0.shape != (rows, _BAND_COLS) or m.band.size > rows * _BAND_COLS:
            raise ValueError("cut tables of another layout")
        return m

    def sample_band(self, image: np.ndarray, i: int) -> np.ndarray:
        """Lens ``i``'s samples of ``image`` (as stored, bilinear) at the band pixels, in the band tables'
        padded layout ``(rows, 4096, C)``: pixel ``k`` of :attr:`band` is ``.reshape(-1, C)[k]``."""
        v = cv2.remap(
            image, self.band_map1[i], self.band_map2[i], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        )
        return v if v.ndim == 3 else v[..., None]


def _clip_is_exact(m0: np.ndarray, m1: np.ndarray, f: float) -> bool:
    """Is the two-lens weight ``clip(0.5 + (m0 - m1) / 2f)`` alone exact everywhere between these nodes?

    Bilinear values lie between a cell's four corners, so per cell: both lenses see throughout, or
    one sees throughout and leads the other by at least ``f`` (its weight saturates at 1, as it is
    where the other does not see). Then no pixel is unseen either.
    """

    def lo(a: np.ndarray) -> np.ndarray:
        return cast(np.ndarray, np.minimum(np.minimum(a[:-1, :-1], a[1:, :-1]), np.minimum(a[:-1, 1:], a[1:, 1:])))

    m0_lo, m1_lo = lo(m0), lo(m1)
    d_lo, d_hi = lo(m0 - m1), -lo(m1 - m0)
    ok = ((m0_lo > 0) & (m1_lo > 0)) | ((m0_lo > 0) & (d_lo >= f)) | ((m1_lo > 0) & (d_hi <= -f))
    return bool(ok.all())


def build_cut_maps(
    profile: LensProfile, in_size: tuple[int, int], out_height: int, R_level: Any = None, feather_deg: float = 10.0
) -> CutMaps:
    """:class:`CutMaps` of a two-lens profile (the weights of :func:`feather_weights` for two lenses, block by
    block)."""
    if len(profile.lenses) != 2:
        raise InputError(f"profile {profile.model!r} has {len(profile.lenses)} lenses; cut tables need 2")
    H, W = out_height, 2 * out_height
    map1 = np.empty((H, W, 2), np.int16)
    map2 = np.empty((H, W), np.uint16)
    lead = np.empty((H, W), np.uint8)
    f = max(math.radians(feather_deg), 1e-6)
    half_inv_f = np.float32(0.5 / f)
    grid = _NodeGrid(profile, in_size, out_height, R_level)
    if grid.s > 1 and all(grid.framed):
        (x0n, y0n, m0_nodes), (x1n, y1n, m1_nodes) = grid.nodes
        dm_nodes = m0_nodes - m1_nodes
        # the dominant lens' coordinates at the nodes: interpolated, they are the table wherever a cell's four nodes
        # agree on the lens; in a cell where they do not, every pixel lies in the feather band (checked per block)
        # and takes both lenses' samples there, blended: what the table says at it is never seen
        lead_nodes = dm_nodes >= 0
        xd_nodes, yd_nodes = np.where(lead_nodes, x0n, x1n), np.where(lead_nodes, y0n, y1n)

    def mixed_cells_in_band(r0: int, r1: int) -> bool:
        """Does every node cell of rows ``r0:r1`` whose nodes disagree on the dominant lens lie in the band?"""
        d = dm_nodes[grid.slab(r0, r1)]
        corners = (d[:-1, :-1], d[1:, :-1], d[:-1, 1:], d[1:, 1:])
        ahead = sum((c >= 0).astype(np.uint8) for c in corners)
        mixed = (ahead > 0) & (ahead < 4)
        if not mixed.any():
            return True
        reach = np.maximum(
            np.maximum(np.abs(corners[0]), np.abs(corners[1])), np.maximum(np.abs(corners[2]), np.abs(corners[3]))
        )
        return bool(np.all(reach[mixed] < 0.9 * f))

    scratch: list[np.ndarray] = []  # one buffer for all blocks: (lens, x / y, rows, W), written only over the runs

    def band_coordinates(r0: int, r1: int, flat: np.ndarray, cols_i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Both lenses' coordinates ``(n, 2)`` at the band pixels (``flat``: their indices in the block, ``cols_i``
        their columns), interpolated over the runs of columns they occupy."""
        if not scratch:
            scratch.append(np.empty((2, 2, max(b - a for a, b in grid.blocks()), W), np.float32))
        used = np.zeros(W, bool)
        used[cols_i] = True
        cols = np.flatnonzero(used)
        runs = np.split(cols, np.flatnonzero(np.diff(cols) > 4 * grid.s) + 1) if cols.size else []
        out = []
        for k, (xn, yn) in enumerate(((x0n, y0n), (x1n, y1n))):
            planes = scratch[0][k]
            for run in runs:
                c0, c1 = int(run[0]), int(run[-1]) + 1
                planes[0, : r1 - r0, c0:c1] = grid.interpolate_columns(xn, r0, r1, c0, c1)
                planes[1, : r1 - r0, c0:c1] = grid.interpolate_columns(yn, r0, r1, c0, c1)
            out.append(np.stack([planes[0].reshape(-1)[flat], planes[1].reshape(-1)[flat]], axis=-1))
        return out[0], out[1]

    def block(rows: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
        """Rows ``r0:r1`` of the tables (written in place); returns the block's band and its covered count."""
        r0, r1 = rows
        if (
            grid.s > 1
            and all(grid.framed)
            and _clip_is_exact(m0_nodes[grid.slab(r0, r1)], m1_nodes[grid.slab(r0, r1)], f)
        ):
            # every pixel of the block is seen, and where a lens does not see the other one's weight
            # saturates: w0 = clip(0.5 + (m0 - m1) / 2f) alone, from the interpolated margin difference
            w0 = grid.interpolate(dm_nodes, r0, r1)
            w0 *= half_inv_f
            w0 += np.float32(0.5)
            np.clip(w0, 0.0, 1.0, out=w0)
            lens0 = w0 >= 0.5
            if mixed_cells_in_band(r0, r1):
                x, y = grid.interpolate(xd_nodes, r0, r1), grid.interpolate(yd_nodes, r0, r1)
                cv2.convertMaps(x, y, cv2.CV_16SC2, dstmap1=map1[r0:r1], dstmap2=map2[r0:r1])
                del x, y
                lead[r0:r1] = lens0
                flat = np.flatnonzero((w0 > 0) & (w0 < 1))
                xy0, xy1 = band_coordinates(r0, r1, flat, flat % W)
                return flat + r0 * W, w0.reshape(-1)[flat], xy0, xy1, lens0.size
            x0, y0, x1, y1 = (grid.interpolate(p, r0, r1) for p in (x0n, y0n, x1n, y1n))
            x = np.where(lens0, x0, x1)
            y = np.where(lens0, y0, y1)
            covered = lens0.size
        else:
            (x0, y0, m0), (x1, y1, m1) = grid.samples(r0, r1)
            # feather_weights for two lenses: w0 = clip(0.5 + (m0 - m1) / 2f) where both see, 1/0 where one does
            w0 = m0 - m1
            w0 *= half_inv_f
            w0 += np.float32(0.5)
            np.clip(w0, 0.0, 1.0, out=w0)
            np.copyto(w0, np.float32(1.0), where=m1 <= 0)
            np.copyto(w0, np.float32(0.0), where=m0 <= 0)
            lens0 = w0 >= 0.5
            x = np.where(lens0, x0, x1)
            y = np.where(lens0, y0, y1)
            unseen = (m0 <= 0) & (m1 <= 0)
            if unseen.any():
                x[unseen] = -10.0
                y[unseen] = -10.0
            covered = unseen.size - int(np.count_nonzero(unseen))
        cv2.convertMaps(x, y, cv2.CV_16SC2, dstmap1=map1[r0:r1], dstmap2=map2[r0:r1])
        lead[r0:r1] = lens0
        rows_i, cols_i = np.divmod(np.flatnonzero((w0 > 0) & (w0 < 1)), W)  # the band: both lenses weigh in
        return (
            rows_i * W + cols_i + r0 * W,
            w0[rows_i, cols_i],
            np.stack([x0[rows_i, cols_i], y0[rows_i, cols_i]], axis=-1),
            np.stack([x1[rows_i, cols_i], y1[rows_i, cols_i]], axis=-1),
            covered,
        )

    parts = [block(rows) for rows in grid.blocks()]  # (two threads: no faster on 2 busy cores, +80 MB peak)
    band, band_w0 = [p[0] for p in parts], [p[1] for p in parts]
    band_xy = ([p[2] for p in parts], [p[3] for p in parts])
    covered = sum(p[4] for p in parts)
    band_idx = np.concatenate(band).astype(np.int32 if H * W < 2**31 else np.int64)
    n = band_idx.size
    rows = max(1, -(-n // _BAND_COLS))
    bm1 = np.empty((2, rows, _BAND_COLS, 2), np.int16)
    bm2 = np.empty((2, rows, _BAND_COLS), np.uint16)
    for k in range(2):
        flat = np.full((rows * _BAND_COLS, 2), -10.0, np.float32)
        flat[:n] = np.concatenate(band_xy[k])
        xy = flat.reshape(rows, _BAND_COLS, 2)
        bm1[k], bm2[k] = cv2.convertMaps(xy[..., 0], xy[..., 1], cv2.CV_16SC2)
    w0 = np.zeros(rows * _BAND_COLS, np.float32)
    w0[:n] = np.concatenate(band_w0)
    return CutMaps(map1, map2, lead, band_idx, w0.reshape(rows, _BAND_COLS), bm1, bm2, covered / (H * W))


def get_cut_maps(
    profile: LensProfile,
    in_size: tuple[int, int],
    out_height: int,
    R_level: Any = None,
    feather_deg: float = 10.0,
    cache_dir: str | os.PathLike[str] | None = None,
) -> tuple[CutMaps, str]:
    """:func:`build_cut_maps` through the in-memory LRU and the optional on-disk cache (as :func:`get_maps`)."""
    R = np.eye(3) if R_level is None else np.asarray(R_level, dtype=np.float64)
    key = _key(profile, in_size, out_height, R, feather_deg)
    return _cached(
        f"cut{CutMaps.LAYOUT}-{key}",
        cache_dir,
        lambda: build_cut_maps(profile, in_size, out_height, R, feather_deg),
        CutMaps.from_arrays,
    )


# sRGB 8-bit -> linear float32 (exact per code value) and linear -> sRGB 8-bit through a 16-bit index
_DECODE_LUT: np.ndarray | None = None
_ENCODE_LUT: np.ndarray | None = None


def srgb8_luts() -> tuple[np.ndarray, np.ndarray]:
    global _DECODE_LUT, _ENCODE_LUT
    if _DECODE_LUT is None:
        _DECODE_LUT = np.asarray(srgb_decode(np.arange(256, dtype=np.float64) / 255.0), np.float32)
        enc = np.asarray(srgb_encode(np.arange(65536, dtype=np.float64) / 65535.0))
        _ENCODE_LUT = np.round(np.clip(enc, 0, 1) * 255.0).astype(np.uint8)
    return _DECODE_LUT, cast(np.ndarray, _ENCODE_LUT)


def encode_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear ``[0, 1]`` float -> sRGB uint8 (IEC 61966-2-1) through a 65536-entry table."""
    _, enc = srgb8_luts()
    x = np.clip(linear, 0.0, 1.0).astype(np.float32, copy=False)
    x *= 65535.0
    np.rint(x, out=x)
    return cast(np.ndarray, enc[x.astype(np.uint16)])


def warp_lens(image: np.ndarray, maps: UnwarpMaps, i: int) -> np.ndarray:
    """Lens ``i``'s image sampled at its map, ``(H, 2H, C)`` float32 *linear* (zeros outside).

    uint8 input is taken as sRGB-encoded: it is interpolated in that encoding (as cameras and
    ffmpeg do) and then decoded to linear exactly per code value.
    """
    w = cv2.remap(image, maps.map1[i], maps.map2[i], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if w.ndim == 2:
        w = w[..., None]
    if image.dtype == np.uint8:
        dec, _ = srgb8_luts()
        return cast(np.ndarray, dec[w])
    return w.astype(np.float32, copy=False)


def _stride(shape: tuple[int, ...], target: int = 1024) -> int:
    return max(1, shape[0] // target)


def match_gains(
    warped: list[np.ndarray],
    maps: UnwarpMaps,
    saturation: float | None = 0.98,
    floor: float = 1e-3,
    scale: np.ndarray | None = None,
) -> np.ndarray:
    """Per-lens, per-channel linear gains ``(L, C)`` equalising the lenses on their overlap.

    ``warped``: each lens' linear view ``(H, 2H, C)``. For two lenses: ``ratio_c = exp(median(log
    I_0 - log I_1))`` over feather-band pixels (both weights > 0; every k-th row and column for
    outputs above 1024 rows) that are neither black (``< floor``) nor saturated (``>= saturation``
    in any channel, for LDR input); lens 0 gets ``ratio^-1/2``, lens 1 ``ratio^+1/2``. More lenses
    are matched to lens 0 and renormalised to a geometric mean of 1. Returns ones when the overlap
    has < 100 usable pixels. ``scale`` ``(L, H, 2H)`` (optional): per-pixel factors already applied
    to ``warped`` (vignetting correction); the black/clipped tests use the values as captured,
    ``warped / scale``.
    """
    L, C = len(warped), warped[0].shape[-1]
    k = _stride(warped[0].shape)
    gains = np.ones((L, C), np.float64)
    valid = maps.weight[:, ::k, ::k] > 0
    for i in range(1, L):
        both = valid[0] & valid[i]
        a, b = warped[0][::k, ::k][both], warped[i][::k, ::k][both]
        a_cap, b_cap = a, b
        if scale is not None:
            a_cap = a / scale[0, ::k, ::k][both][:, None]
            b_cap = b / scale[i, ::k, ::k][both][:, None]
        ok = np.all((a_cap > floor) & (b_cap > floor), axis=-1)
        if saturation is not None:
            ok &= np.all((a_cap < saturation) & (b_cap < saturation), axis=-1)
        if ok.sum() < 100:
            continue
        gains[i] = np.exp(np.median(np.log(a[ok]) - np.log(b[ok]), axis=0))
    gains /= np.exp(np.mean(np.log(gains), axis=0, keepdims=True))
    return gains


def seam_disagreement(warped: list[np.ndarray], maps: UnwarpMaps, gains: np.ndarray | None = None) -> dict[str, float]:
    """Photometric disagreement of lenses 0 and 1 on their overlap (after ``gains``).

    Returns ``{"seam_mad": median |I_0 - I_1|, "seam_rmse": ..., "overlap_px": n}`` over the
    feather band (pixels where both lenses have weight > 0; channel-averaged, image units; every
    k-th row and column for outputs above 1024 rows, ``overlap_px`` counts the full band).
    """
    nan = {"seam_mad": math.nan, "seam_rmse": math.nan, "overlap_px": 0}
    if len(warped) < 2:
        return nan
    k = _stride(warped[0].shape)
    g = np.ones((len(warped), warped[0].shape[-1])) if gains is None else gains
    both = (maps.weight[0, ::k, ::k] > 0) & (maps.weight[1, ::k, ::k] > 0)
    diff = (warped[0][::k, ::k][both] * g[0] - warped[1][::k, ::k][both] * g[1]).mean(axis=-1)
    if diff.size == 0:
        return nan
    return {
        "seam_mad": float(np.median(np.abs(diff))),
        "seam_rmse": float(np.sqrt(np.mean(diff**2))),
        "overlap_px": int(((maps.weight[0] > 0) & (maps.weight[1] > 0)).sum()),
    }


def read_input(path: Path) -> tuple[np.ndarray, float | None]:
    """A capture file as the input of :func:`solidkit.capture.unwarp.unwarp`, and its linear clipping level (None
    for HDR/raw).

    EXR: linear float; raw/DNG: linear float (:func:`solidkit.camera.raw.read_raw`); 8-bit LDR:
    uint8 RGB as stored (sRGB-encoded; :func:`solidkit.capture.unwarp.unwarp` decodes per code value). 16-bit LDR is
    decoded to linear float.
    """
    if path.suffix.lower() == ".exr":
        img, _ = read_exr(path)
        if not np.isfinite(img[..., :3]).all():
            raise InputError(f"{path}: {int((~np.isfinite(img[..., :3])).any(-1).sum())} pixel(s) are NaN or Inf")
        return img[..., :3], None
    if is_raw_file(path):
        return read_raw(path).linear, None
    raw = imread(path)
    if raw.dtype != np.uint8:
        return read_ldr(path, linear=True), 0.98
    if raw.ndim == 2:
        raw = np.repeat(raw[..., None], 3, axis=2)
    return cv2.cvtColor(np.ascontiguousarray(raw[..., :3]), cv2.COLOR_BGR2RGB), float(srgb8_luts()[0][250])


def read_linear(path: Path) -> tuple[np.ndarray, float | None]:
    """:func:`read_input` with 8-bit images decoded to linear float32."""
    img, sat = read_input(path)
    if img.dtype == np.uint8:
        img = srgb8_luts()[0][img]
    return img, sat
