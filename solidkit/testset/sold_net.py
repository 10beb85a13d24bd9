"""The real-set layout of SOLD-Net (Tang et al., ECCV 2022), written from a test set and read back.

SOLD-Net's README ("Real data") documents a flat folder, one item ``<XXX>`` (001, 002, ...) per
scene::

    <XXX>_persp.jpg      the limited-FOV LDR photo, 320x240
    <XXX>_local.npy      the marked pixel positions of the local lighting maps in that photo
    <XXX>_local_0.hdr    the HDR local lighting maps (Radiance RGBE), 128x64 equirect,
    <XXX>_local_1.hdr    one per marked position
    <XXX>_sun_pos.txt    the sun position label (absent: no sun)

and its loader (``estimating/data/dataset_real.py``) pins the details: items are found with
``glob('*_persp.*')`` and kept only when ``_local.npy``, ``_local_0.hdr`` and ``_local_1.hdr``
exist; the photo is opened as ``<XXX>_persp.JPG`` (upper-case suffix, so this writer uses it: the
glob matches either case, the open does not); ``local_pos`` is an integer ``(N, 2)`` array of
``(row, col)`` pixels (the estimator indexes ``local_pos // 4`` into its 60x80 feature map, rows
first); ``sun_pos`` is ``np.loadtxt`` of ``(col, row)`` on the 128x32 upper-hemisphere grid,
converted by their test script as ``azimuth = (col - 63.5) / 64 * 180``, ``elevation =
(31.5 - row) / 64 * 180`` (degrees) — the same equirect layout as conventions §3 (azimuth 0 at
the centre column, growing to the right; row 0 at the zenith) restricted to the top half of a
128x64 map. We write the sub-cell (fractional) position so nothing is lost; their code uses it as
a number. Their documents do not say which direction azimuth 0 is; we export with azimuth 0 = the
photo's view direction projected on the horizon (our panorama frame, as in SOLID-Net), which is
what their estimator's use of the photo implies but not something we could check against their
data. An item with fewer than two probes is written but SOLD-Net's loader skips it (reported).

The photo is the 320x240 model input, as JPEG (quality 95); a photo that already is a 320x240 JPEG
is copied byte for byte. Local maps are our HDR probes (photo panorama frame) resized to 128x64
with the radiance-preserving :func:`solidkit.envmap.resample.resize`; a probe without a bracket is
exported from its LDR (sRGB-decoded, clipped, relative units) and marked ``ldr_derived`` in
``solidkit_items.json``, the only extra file (ignored by their glob). The way back is
:mod:`solidkit.testset.sold_net_import`.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from solidkit.envmap.coords import angles_from_coords, coords_from_angles
from solidkit.envmap.io import read_exr, read_ldr, srgb_decode
from solidkit.envmap.resample import resize
from solidkit.errors import InputError
from solidkit.fsutil import atomic_path, atomic_write_text
from solidkit.testset.build import load_testset
from solidkit.testset.schema import MODEL_INPUT_SIZE, Scene

__all__ = [
    "LOCAL_HEIGHT",
    "SUN_GRID",
    "sun_grid_position",
    "sun_angles",
    "export_sold_net",
    "SoldNetItem",
    "read_sold_net",
]

LOCAL_HEIGHT = 64  # 128x64 local maps
SUN_GRID = (128, 32)  # columns, rows of the sun-position grid (upper hemisphere)
JPEG_QUALITY = 95
ITEMS_FILE = "solidkit_items.json"


def sun_grid_position(azimuth_deg: float, elevation_deg: float) -> tuple[float, float]:
    """``(col, row)`` on SOLD-Net's 128x32 grid of a direction (degrees): the pixel-centre
    coordinates in the top half of a 128x64 equirect map (conventions §3), i.e.
    ``col = azimuth * 64 / 180 + 63.5``, ``row = 31.5 - elevation * 64 / 180``."""
    x, y = coords_from_angles(math.radians(azimuth_deg), math.radians(elevation_deg), LOCAL_HEIGHT)
    return float(x) - 0.5, float(y) - 0.5


def sun_angles(col: float, row: float) -> tuple[float, float]:
    """Inverse of :func:`sun_grid_position`: ``(azimuth_deg, elevation_deg)`` (SOLD-Net's test script)."""
    phi, theta = angles_from_coords(col + 0.5, row + 0.5, LOCAL_HEIGHT)
    return math.degrees(phi), math.degrees(theta)


def _write_image(path: Path, image: np.ndarray, params: list[int] | None = None) -> None:
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image, params or []):
            raise InputError(f"{path}: OpenCV could not write it")


def _is_model_input_jpeg(scene: Scene) -> bool:
    """The original photo is a JPEG that is the model input itself (320x240, nothing cropped)."""
    w, h = MODEL_INPUT_SIZE
    return Path(scene.photo_full).suffix.lower() in (".jpg", ".jpeg") and tuple(scene.crop_box) == (0, 0, w, h)


def export_sold_net(root: str | os.PathLike, dest: str | os.PathLike) -> dict[str, Any]:
    """Write the test set at ``root`` into ``dest`` in SOLD-Net's real-set layout; returns the item map.

    ``dest`` must be absent, empty or an earlier export (holding ``solidkit_items.json``), outside the test set.
    """
    root, dest = Path(root), Path(dest)
    ts = load_testset(root)
    if dest.resolve() == root.resolve() or root.resolve() in dest.resolve().parents:
        raise InputError(f"{dest}: write the export outside the test set (its files are checksummed)")
    if dest.exists() and (not dest.is_dir() or (any(dest.iterdir()) and not (dest / ITEMS_FILE).is_file())):
        raise InputError(
            f"{dest}: exists and is not an earlier SOLD-Net export (no {ITEMS_FILE}); refusing to write there"
        )
    dest.mkdir(parents=True, exist_ok=True)
    for stale in dest.glob("[0-9][0-9][0-9]_*"):  # an earlier export: items are rewritten from scratch
        stale.unlink()
    items, skipped = {}, []
    for i, scene in enumerate(ts.scenes):
        xxx = f"{i + 1:03d}"
        if _is_model_input_jpeg(scene):  # already their photo: its bytes, no second JPEG generation
            with atomic_path(dest / f"{xxx}_persp.JPG") as tmp:
                shutil.copyfile(root / scene.photo_full, tmp)
        else:
            photo = cv2.imread(str(root / scene.photo), cv2.IMREAD_COLOR)
            assert photo is not None, f"{root / scene.photo}: OpenCV could not read it"
            _write_image(dest / f"{xxx}_persp.JPG", photo, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        pos = np.array(
            [[int(round(p.pixel[1])), int(round(p.pixel[0]))] for p in scene.probes], dtype=np.int64
        ).reshape(-1, 2)
        with atomic_path(dest / f"{xxx}_local.npy") as tmp:
            np.save(tmp, pos)
        sources = []
        for k, p in enumerate(scene.probes):
            if p.hdr is not None:
                hdr, source = read_exr(root / p.hdr)[0][..., :3], "hdr"
            else:
                hdr, source = srgb_decode(read_ldr(root / p.ldr)), "ldr_derived"
            local = np.maximum(resize(hdr.astype(np.float32), LOCAL_HEIGHT), 0.0)
            _write_image(dest / f"{xxx}_local_{k}.hdr", np.ascontiguousarray(local[..., ::-1]).astype(np.float32))
            sources.append(source)
        if scene.sun.found:
            assert scene.sun.azimuth_deg is not None and scene.sun.elevation_deg is not None  # a found sun has both
            col, row = sun_grid_position(scene.sun.azimuth_deg, scene.sun.elevation_deg)
            atomic_write_text(dest / f"{xxx}_sun_pos.txt", f"{col:.6f}\n{row:.6f}\n")
        if len(scene.probes) < 2:
            skipped.append(xxx)
        items[xxx] = {
            "scene": scene.id,
            "probes": [p.id for p in scene.probes],
            "local_sources": sources,
            "sun_found": scene.sun.found,
        }
    doc = {
        "format": "sold-net-real",
        "testset": ts.dataset_version,
        "items": items,
        "skipped_by_sold_net_loader": skipped,
        "note": "local_pos rows are (row, col) in the 320x240 photo; sun_pos is (col, row) on the 128x32 grid",
    }
    atomic_write_text(dest / ITEMS_FILE, json.dumps(doc, indent=1, sort_keys=True) + "\n")
    return doc


@dataclass
class SoldNetItem:
    """One item of a SOLD-Net real folder, as its loader sees it."""

    id: str
    persp: np.ndarray  # (240, 320, 3) RGB float32 in [0, 1]
    local_pos: np.ndarray  # (N, 2) int, (row, col)
    local_pano: np.ndarray  # (N, 64, 128, 3) float32 linear RGB
    sun_pos: np.ndarray  # (2,) (col, row), or (-1, -1) without a sun
    is_sunny: bool
    loadable: bool = True  # SOLD-Net's loader keeps it (has _local_0 and _local_1)
    sun_deg: tuple[float, float] | None = field(default=None)


def read_sold_net(folder: str | os.PathLike) -> list[SoldNetItem]:
    """Read a folder in SOLD-Net's documented real-set layout (see the module docstring).

    Every item with a ``_persp`` photo and a ``_local.npy`` is returned; ``loadable`` says whether
    SOLD-Net's own loader would keep it.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    out = []
    for persp in sorted(folder.glob("*_persp.*")):
        xxx = persp.name.split("_")[0]
        pos_file = folder / f"{xxx}_local.npy"
        if not pos_file.is_file():
            continue
        img = cv2.imread(str(persp), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(f"{persp}: not a readable image")
        pos = np.load(pos_file)
        if pos.ndim != 2 or pos.shape[1] != 2 or not np.issubdtype(pos.dtype, np.integer):
            raise InputError(f"{pos_file}: expected an integer (N, 2) array of (row, col), got {pos.dtype} {pos.shape}")
        panos = []
        for k in range(pos.shape[0]):
            f = folder / f"{xxx}_local_{k}.hdr"
            hdr = cv2.imread(str(f), cv2.IMREAD_UNCHANGED) if f.is_file() else None
            if hdr is None:
                raise InputError(f"{f}: missing or not a Radiance HDR file")
            panos.append(hdr[..., ::-1].astype(np.float32))
        sun_file = folder / f"{xxx}_sun_pos.txt"
        sun = np.loadtxt(sun_file) if sun_file.is_file() else np.array([-1.0, -1.0])
        sunny = bool(sun[0] >= 0)
        out.append(
            SoldNetItem(
                id=xxx,
                persp=img[..., ::-1].astype(np.float32) / 255.0,
                local_pos=pos,
                local_pano=np.stack(panos) if panos else np.zeros((0, LOCAL_HEIGHT, 2 * LOCAL_HEIGHT, 3), np.float32),
                sun_pos=sun,
                is_sunny=sunny,
                loadable=(folder / f"{xxx}_local_0.hdr").is_file() and (folder / f"{xxx}_local_1.hdr").is_file(),
                sun_deg=sun_angles(float(sun[0]), float(sun[1])) if sunny else None,
            )
        )
    return out
