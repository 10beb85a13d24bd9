"""``solidkit testset import --format sold-net DIR TESTSET``: SOLD-Net's real-set folder as a solidkit test set.

The folder is read as SOLD-Net's loader reads it (:func:`solidkit.testset.sold_net.read_sold_net`;
their layout and frames are described in :mod:`solidkit.testset.sold_net`). Every conversion below
is the inverse of :func:`~solidkit.testset.sold_net.export_sold_net`, so a folder written by our
exporter imports back to the same values (tested; exact where the files are), and what their
layout does not hold is written as an explicit assumption (a flag), never as a measurement.

Conversion (frames: ``docs/conventions.md``)
-------------------------------------------
- **photo**: ``<XXX>_persp.*`` is copied byte for byte as ``photo_full``; ``photo.png`` is its
  centre crop/resize to 320x240 (a 320x240 photo is decoded and re-encoded losslessly).
- **intrinsics**: their layout records none. ``K`` is that of an ideal pinhole with the horizontal
  field of view ``hfov_deg`` (default: SOLID-Net's training FOV), flagged ``no_intrinsics``.
- **pitch, roll**: the photo camera's tilt against the (gravity-aligned) maps and sun grid is not
  recorded; 0, flagged ``photo_pitch_roll_assumed_zero``.
- **probe pixels**: ``local_pos`` rows are integer ``(row, col)`` indices of the 320x240 photo;
  OpenCV pixel centres are at integers (conventions §1), so ``pixel = [col, row]`` with no
  offset. A negative entry is decoded as SOLD-Net's test script does (``-p - 1``) and flagged.
- **local maps**: ``<XXX>_local_<i>.hdr`` (128x64 equirect, linear RGB as stored, relative units)
  are in our panorama frame already (azimuth 0 = the photo's view direction on the horizon,
  growing to the right, row 0 = zenith: conventions §3); ``hdr_full.exr`` holds them unchanged and
  ``hdr.exr`` is the 256x128 probe, upsampled with the radiance-preserving
  :func:`solidkit.envmap.resample.resize` (pixel replication: downsampling it again gives the
  128x64 map back up to float rounding). ``rotation`` is the identity.
- **LDR probes**: their layout has none; ``ldr.png`` is the map as an auto-exposed 8-bit sRGB
  capture (:func:`solidkit.metrics.maps.simulate_ldr_probe`, as ``solidkit eval`` makes the LDR
  truth of a synthetic probe: mean luminance to 0.18, clipped), ``saturation.png`` its clipped
  pixels. (A fixed exposure such as SOLD-Net's test's ``2^-2`` clips most of a map in our units.)
- **sun**: ``sun_pos.txt`` ``(col, row)`` on their 128x32 grid through
  :func:`~solidkit.testset.sold_net.sun_angles`; no file = no sun (their ``is_sunny``). Their
  labels are quantised to grid cells of ``180/64 = 2.8125`` degrees: ``uncertainty_deg`` is the
  1-sigma angular error of a direction uniformly distributed in its cell,
  ``cell / sqrt(12) * sqrt(1 + cos^2 elevation)`` (about 1.15 degrees at the horizon).
- **provenance**: pixels and the sun are labels of the SOLD-Net team (source ``annotator``,
  annotator ``sold-net``); ids are ``<XXX>`` and ``p0``, ``p1``, ... unless the folder holds our
  exporter's ``solidkit_items.json``, whose scene and probe ids are restored. ``inputs`` has no
  campaign manifest or alignment to hash: both hashes are of the folder's listing
  (``"<name> <sha256>"`` per file).

Items that SOLD-Net's own loader skips (fewer than two local maps) are imported too and listed in
the report; items without any local map are left out (a test set scene needs a probe).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from solidkit import __version__
from solidkit.envmap.coords import CONVENTIONS_VERSION, direction_from_angles, solid_angle
from solidkit.envmap.io import read_ldr, write_exr, write_ldr
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.envmap.resample import resize
from solidkit.errors import InputError
from solidkit.flags import FlagCode
from solidkit.fsutil import sha256_file
from solidkit.testset.build import (
    MANIFEST_FILE,
    _check_out,
    _files,
    _swap,
    _write_u8,
    pixel_to_model,
)
from solidkit.testset.schema import (
    MODEL_INPUT_SIZE,
    PROBE_SIZE,
    Alignment,
    Inputs,
    PhotoCapture,
    Probe,
    ProbeImages,
    Scene,
    Sun,
    TestSet,
    canonical_json,
    content_version,
)
from solidkit.testset.sold_net import ITEMS_FILE, SoldNetItem, read_sold_net

__all__ = ["SUN_CELL_DEG", "ImportReport", "sun_cell_uncertainty_deg", "import_sold_net"]

SUN_CELL_DEG = 180.0 / 64.0  # one cell of SOLD-Net's 128x32 sun grid, degrees (both axes)
ANNOTATOR = "sold-net"


def sun_cell_uncertainty_deg(elevation_deg: float) -> float:
    """1-sigma angular error (degrees) of a direction uniform in one grid cell at ``elevation_deg``.

    Offsets uniform over a cell of width ``c`` have variance ``c^2 / 12`` per axis; an azimuth offset
    spans ``cos(elevation)`` times its angle on the sphere.
    """
    c = math.cos(math.radians(elevation_deg))
    return SUN_CELL_DEG / math.sqrt(12.0) * math.sqrt(1.0 + c * c)


@dataclass
class ImportReport:
    """What :func:`import_sold_net` did."""

    dataset_version: str = ""
    scenes: int = 0
    probes: int = 0
    sun_found: int = 0
    skipped_by_sold_net_loader: list[str] = field(default_factory=list)
    excluded: list[str] = field(default_factory=list)
    ids_from: str = "layout"  # or ITEMS_FILE

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _ids(folder: Path, items: list[SoldNetItem]) -> tuple[dict[str, tuple[str, list[str]]], str]:
    """Scene and probe ids per item: our exporter's when its items file matches the folder, else the layout's."""
    default = {it.id: (it.id, [f"p{k}" for k in range(len(it.local_pos))]) for it in items}
    path = folder / ITEMS_FILE
    if not path.is_file():
        return default, "layout"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        known = {
            xxx: (str(v["scene"]), [str(p) for p in v["probes"]])
            for xxx, v in doc["items"].items()
            if isinstance(v, dict)
        }
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise InputError(f"{path}: not an items file of solidkit's SOLD-Net export ({exc})") from None
    if set(known) != set(default) or any(len(known[k][1]) != len(default[k][1]) for k in default):
        return default, "layout"  # edited since the export: the layout is the truth
    return known, ITEMS_FILE


def _saturated_fraction(mask: np.ndarray) -> float:
    w = solid_angle(mask.shape[0])
    return float((w * mask).sum() / w.sum())


def _probe(
    root: Path, d: str, pid: str, hdr_full: np.ndarray, pixel: tuple[float, float], pixel_full: tuple[float, float]
) -> Probe:
    hdr = resize(hdr_full, PROBE_SIZE[1])
    paths = {k: f"{d}/{k}{ext}" for k, ext in (("hdr", ".exr"), ("hdr_full", ".exr"))}
    meta = {"frame": "photo panorama frame (conventions §2, §8)", "units": "relative (as stored by SOLD-Net)"}
    write_exr(root / paths["hdr"], hdr, meta)
    write_exr(root / paths["hdr_full"], hdr_full, meta)
    from solidkit.metrics.maps import simulate_ldr_probe  # lazy: pulls in torch

    for name, image in (("", hdr), ("_full", hdr_full)):
        ldr, sat = simulate_ldr_probe(image)
        _write_u8(root / f"{d}/ldr{name}.png", ldr[..., ::-1] * 255.0)
        _write_u8(root / f"{d}/saturation{name}.png", sat.astype(np.float32) * 255.0)
        if name == "":
            fraction = _saturated_fraction(sat)
    images = ProbeImages(
        ldr=f"{d}/ldr.png",
        ldr_full=f"{d}/ldr_full.png",
        hdr=paths["hdr"],
        hdr_full=paths["hdr_full"],
        saturation=f"{d}/saturation.png",
        saturation_full=f"{d}/saturation_full.png",
        ldr_full_size=(int(hdr_full.shape[1]), int(hdr_full.shape[0])),
        saturated_fraction=fraction,
    )
    return Probe(
        id=pid,
        pixel=pixel,
        pixel_full=pixel_full,
        pixel_source="annotator",
        pixel_annotator=ANNOTATOR,
        ldr=images.ldr,
        hdr=images.hdr,
        rotation=np.eye(3).tolist(),
        alignment=Alignment(yaw_deg=0.0, source="annotator", annotator=ANNOTATOR),
        images=images,
    )


def _sun(item: SoldNetItem) -> Sun:
    if not item.is_sunny or item.sun_deg is None:
        return Sun(found=False, source="annotator", annotator=ANNOTATOR)
    az, el = item.sun_deg
    return Sun(
        found=True,
        azimuth_deg=az,
        elevation_deg=el,
        uncertainty_deg=sun_cell_uncertainty_deg(el),
        direction=[float(v) for v in direction_from_angles(math.radians(az), math.radians(el))],
        source="annotator",
        annotator=ANNOTATOR,
    )


def _scene(root: Path, folder: Path, item: SoldNetItem, sid: str, pids: list[str], hfov_deg: float) -> Scene:
    persp = next(p for p in sorted(folder.glob(f"{item.id}_persp.*")))
    d = f"scenes/{sid}"
    (root / d).mkdir(parents=True)
    photo_full = f"{d}/photo_full{persp.suffix.lower()}"
    shutil.copyfile(persp, root / photo_full)
    image = read_ldr(persp)
    h, w = image.shape[:2]
    K_full = intrinsics_from_fov(math.radians(hfov_deg), w, h)
    from solidkit.calibration.camera import resize_crop

    small, K, box = resize_crop(image, K_full, MODEL_INPUT_SIZE)
    assert small is not None  # given an image, resize_crop returns one
    write_ldr(root / f"{d}/photo.png", small)
    probes = []
    for k, pid in enumerate(pids):
        row, col = (int(v) for v in item.local_pos[k])
        flags = []
        if row < 0 or col < 0:
            row, col = -row - 1, -col - 1
            flags.append("sold_net_negative_position: stored as -(row, col) - 1 (decoded as their test script does)")
        pixel_full = (float(col), float(row))
        pixel = pixel_to_model(pixel_full, K_full, K)
        p = _probe(root, f"{d}/probes/{pid}", pid, item.local_pano[k], pixel, pixel_full)
        p.flags = flags
        probes.append(p)
    return Scene(
        id=sid,
        photo=f"{d}/photo.png",
        photo_full=photo_full,
        photo_size=MODEL_INPUT_SIZE,
        photo_full_size=(int(w), int(h)),
        crop_box=tuple(int(v) for v in box),
        K=K.tolist(),
        K_full=K_full.tolist(),
        K_source=f"assumed: ideal pinhole, {hfov_deg:g} deg horizontal FOV (SOLD-Net's layout records no intrinsics)",
        pitch_deg=0.0,
        roll_deg=0.0,
        sun=_sun(item),
        probes=probes,
        capture=PhotoCapture(original_sha256=sha256_file(persp)),
        flags=[
            f"{FlagCode.NO_INTRINSICS.value}: K assumed from a {hfov_deg:g} deg horizontal FOV",
            f"{FlagCode.PHOTO_PITCH_ROLL_ASSUMED_ZERO.value}: SOLD-Net's layout records no camera pitch or roll",
        ],
        notes=f"imported from SOLD-Net's real-set layout, item {item.id}",
    )


def _listing_sha(folder: Path) -> str:
    """SHA-256 of ``"<name> <sha256>\\n"`` over the folder's files (what an imported set was built from)."""
    lines = "".join(f"{p.name} {sha256_file(p)}\n" for p in sorted(folder.iterdir()) if p.is_file())
    return hashlib.sha256(lines.encode("utf-8")).hexdigest()


def import_sold_net(
    folder: str | os.PathLike, out: str | os.PathLike, *, hfov_deg: float | None = None
) -> ImportReport:
    """Write the SOLD-Net real-set folder ``folder`` as a solidkit test set at ``out`` (see the module docstring).

    ``out`` must be absent, empty or an earlier test set, outside ``folder``; it is replaced as a
    whole (assembled beside it, then renamed in). ``hfov_deg``: the photos' horizontal field of
    view in degrees (default: SOLID-Net's training FOV, flagged as assumed either way).
    """
    folder, out = Path(folder), Path(out)
    if hfov_deg is None:
        from solidkit.model.config import SolidNetConfig

        hfov_deg = SolidNetConfig().hfov_deg
    o, f = out.resolve(), folder.resolve()
    if o == f or f in o.parents or o in f.parents:
        raise InputError(
            f"{out}: the test set folder must be outside the SOLD-Net folder {folder} (and not contain it)"
        )
    _check_out(out, folder)
    items = read_sold_net(folder)
    if not items:
        raise InputError(f"{folder}: no SOLD-Net item (<XXX>_persp.jpg with <XXX>_local.npy)")
    ids, ids_from = _ids(folder, items)
    report = ImportReport(ids_from=ids_from)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.import-", dir=out.parent))
    try:
        scenes = []
        for item in items:
            sid, pids = ids[item.id]
            if not pids:
                report.excluded.append(f"{item.id}: no local lighting map")
                continue
            if not item.loadable:
                report.skipped_by_sold_net_loader.append(item.id)
            scenes.append(_scene(staging, folder, item, sid, pids, hfov_deg))
        if not scenes:
            raise InputError(f"{folder}: no item with a local lighting map")
        scenes.sort(key=lambda s: s.id)
        ts = TestSet(
            conventions_version=CONVENTIONS_VERSION,
            solidkit_version=__version__,
            inputs=Inputs(
                campaign=f"sold-net:{folder.resolve().name}",
                manifest_sha256=_listing_sha(folder),
                alignment_sha256=_listing_sha(folder),
            ),
            scenes=scenes,
            files=_files(staging),
        )
        ts.dataset_version = content_version(ts)
        (staging / MANIFEST_FILE).write_text(canonical_json(ts.model_dump(mode="json")), encoding="utf-8")
        _swap(staging, out)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    report.dataset_version = ts.dataset_version
    report.scenes = len(scenes)
    report.probes = sum(len(s.probes) for s in scenes)
    report.sun_found = sum(s.sun.found for s in scenes)
    return report
