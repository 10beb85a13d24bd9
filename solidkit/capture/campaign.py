"""Campaign ingest: SD cards -> content-addressed originals, a manifest, and derived products.

``solidkit ingest CARD_DIR CAMPAIGN_DIR [--jobs N]`` copies every capture on a card once into
``CAMPAIGN_DIR/originals/<sha[:2]>/<sha256>.<ext>`` (read-only, byte-identical, verified),
reads its metadata, groups the shots into scenes, probe positions and brackets, derives the
products (merged HDR per bracket, the low-exposure sun frame per probe) and records everything
in ``CAMPAIGN_DIR/manifest.json`` (:class:`Manifest`, a pydantic schema with a schema version
and the solidkit version).

Card layout
-----------
Files are found recursively below CARD_DIR in sorted order. Hidden entries (``.*``, macOS ``._*``)
and files not ending in ``.jpg``/``.jpeg``/``.dng`` (any case; e.g. ``.MP4``, ``.THM``, ``.txt``)
are *unrelated*: listed as skipped, never copied. Two layouts are understood, per file:

1. **Explicit** (recommended; the synthetic campaign generator writes this)::

       CARD_DIR/<scene>/photo/<name>.jpg          the scene's normal photo(s)      -> kind "photo"
       CARD_DIR/<scene>/<probe>/<name>.jpg|.dng   Theta shots at probe position <probe>
       CARD_DIR/<scene>/<name>.jpg|.dng           Theta shots of <scene>; probes split by time

   ``<scene>``/``<probe>`` folder names are the ids (deeper sub-folders are allowed and ignored).
   A first-level folder named ``DCIM`` or shaped like a DCF folder (``100RICOH``) is not a scene.

2. **Automatic** (a camera's own ``DCIM/100RICOH/R0010001.JPG`` card): by capture time (EXIF
   ``DateTimeOriginal``, camera clock; keep the cameras' clocks set). Shots of the whole campaign
   are sorted by time; a gap above ``scene_gap_s`` (default 600 s) starts a new scene
   (``scene-YYYYMMDD-HHMMSS`` of its first shot); within a scene a gap above ``probe_gap_s``
   (default 45 s, from the end of one Theta shot to the next) starts a new probe (``p01``,
   ``p02``, ...). Shots without a timestamp go to scene ``undated``, probe ``p01``. A non-Theta
   image (not a Ricoh equirect/dual-fisheye capture) is a **photo**; it joins the scene whose
   time span (± ``scene_gap_s``) contains it, so a photo camera's card can be ingested after
   the Theta's card into the same campaign.

Within a probe, Theta shots are grouped into brackets (:mod:`solidkit.capture.brackets`:
time gaps <= ``bracket_gap_s``, distinct exposures). Kinds: ``bracket_member`` (a group of two
or more), ``low_exposure`` (a single shot at <= ``low_exposure_max_s``, default 1/4000 s: the sun
frame), ``probe`` (any other single shot), ``photo``.

Products (``CAMPAIGN_DIR/products/<scene>/<probe>/``)
-----------------------------------------------------
- ``hdr``: each bracket merged to linear HDR EXR (:func:`solidkit.capture.merge.merge_frames`,
  response curve from ``--response`` or the sRGB inverse) in the capture's layout, then made a
  panorama in the panorama frame (:func:`to_panorama`: dual-fisheye unwarped through the shipped
  lens profile of the camera model, or the per-unit profile given with ``--profile``, each lens
  first divided by its falloff when a ``--vignetting`` profile is given, to a panorama as wide as
  the capture like ``solidkit capture unwarp``; stitched input levelled from its gravity when the
  camera did not; untouched otherwise). Without a fitting profile the EXR keeps the capture
  layout (``layout``) and says why in ``stats["panorama"]``.
- ``sun_frame``: the probe's shortest exposure at or below ``low_exposure_max_s`` (a low-exposure
  shot, else the shortest bracket member), kept as an LDR panorama plus its exposure (time,
  f-number, ISO): the original JPEG itself when it is a level equirect image (no resampling; the
  sun disk saturates anyway: it gives a position, not an intensity), else an 8-bit sRGB PNG of
  :func:`to_panorama`.

Each product records its inputs (sha256), a recipe (tool, parameters, response-curve sha256;
for dual-fisheye products also the lens and vignetting profiles and the panorama size), the
solidkit version and the output's sha256: it is reproducible from originals + profiles + that
version; a product whose recipe changed (other parameters, profiles or solidkit version) is
rebuilt on the next run. Profiles given with ``--response``, ``--profile`` or ``--vignetting``
are copied into ``CAMPAIGN_DIR/profiles/`` under their content hash and recorded in the
manifest; later runs keep using them until another one is given.

Robustness
----------
Everything is written atomically (temporary file + rename: a killed run never leaves a
half-written file under a final name; stray temporaries are removed by the next run). The
manifest is saved every second during the copy phase; a run killed with ``kill -9`` is resumed
by running the same command again (originals already present are verified by size and not
copied again) and ends with the same manifest as an uninterrupted run: the manifest holds no
timestamps of the run and is a pure function of the cards' files and the grouping parameters.
Per-file problems (empty, truncated or undecodable files, a DNG named ``.jpg``) are collected and
reported at the end while the other files are processed; they are kept in the manifest's
``errors`` (keyed by path, size and mtime) so that an unchanged bad file is not retried. A second
run over the same card does nothing and says so. An exclusive lock (``CAMPAIGN_DIR/.lock``)
prevents two ingests into one campaign at once.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import math
import os
import re
import shutil
import stat
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, Field

from solidkit.errors import InputError, SolidkitError
from solidkit.fsutil import atomic_path, atomic_write_text, sha256_file

__all__ = [
    "SCHEMA_VERSION",
    "GroupingParams",
    "SourceRef",
    "Shot",
    "Bracket",
    "Probe",
    "Scene",
    "Product",
    "FileError",
    "Manifest",
    "IngestReport",
    "ingest",
    "load_manifest",
    "scan_card",
    "group_shots",
    "planned_products",
    "to_panorama",
]

SCHEMA_VERSION = 1
MANIFEST_NAME = "manifest.json"
IMAGE_SUFFIXES = {".jpg": ".jpg", ".jpeg": ".jpg", ".dng": ".dng"}
_DCF = re.compile(r"^\d{3}[A-Za-z0-9_]{5}$")
_THETA_TYPES = {"equirect", "dual_fisheye", "dual_fisheye_upright"}
ShotKind = Literal["photo", "probe", "low_exposure", "bracket_member"]


# --------------------------------------------------------------------------- schema
class GroupingParams(BaseModel):
    """How shots are grouped (seconds). Stored in the manifest; changing them regroups."""

    scene_gap_s: float = 600.0
    probe_gap_s: float = 45.0
    bracket_gap_s: float = 10.0
    low_exposure_max_s: float = 1.0 / 4000.0


class SourceRef(BaseModel):
    """Where a shot was found: card directory, path relative to it (POSIX), size and mtime."""

    card: str
    path: str
    size: int
    mtime_ns: int


class Shot(BaseModel):
    """One original capture (content-addressed) with its metadata and its place in the campaign."""

    sha256: str
    original: str = Field(description="path relative to the campaign directory")
    size: int
    file_format: str
    sources: list[SourceRef]
    metadata: dict[str, Any] = Field(description="solidkit.camera.metadata.CaptureMetadata, as JSON")
    layout_scene: str | None = Field(None, description="scene id given by the card's folder layout")
    layout_probe: str | None = Field(None, description="probe id (or 'photo') given by the folder layout")
    kind: ShotKind | None = None
    scene: str | None = None
    probe: str | None = None
    bracket: str | None = None


class Bracket(BaseModel):
    """An exposure bracket: member shots (capture order) and their exposure times (s)."""

    id: str
    shots: list[str]
    exposure_times: list[float | None]


class Probe(BaseModel):
    """A probe position: the Theta shots taken there."""

    id: str
    shots: list[str]
    brackets: list[Bracket] = Field(default_factory=list)
    sun_frame: str | None = Field(None, description="sha256 of the shot kept as the sun frame")
    warnings: list[str] = Field(default_factory=list)


class Scene(BaseModel):
    """A scene: its photos and probe positions; times are the camera clock (naive)."""

    id: str
    grouping: Literal["folder", "time", "undated"]
    start: datetime | None = None
    end: datetime | None = None
    photos: list[str] = Field(default_factory=list)
    probes: list[Probe] = Field(default_factory=list)


class Product(BaseModel):
    """A derived file: reproducible from its inputs, recipe and solidkit version."""

    id: str
    kind: Literal["hdr", "sun_frame"]
    scene: str
    probe: str
    inputs: list[str] = Field(description="sha256 of the originals, in order")
    path: str | None = Field(None, description="relative to the campaign directory")
    sha256: str | None = None
    layout: str = Field("unknown", description="image type of the product's pixels")
    exposure_time: float | None = Field(None, description="seconds (sun frame; HDR: first frame)")
    f_number: float | None = None
    iso: float | None = None
    recipe: dict[str, Any] = Field(default_factory=dict)
    recipe_hash: str = ""
    solidkit_version: str = ""
    stats: dict[str, Any] = Field(default_factory=dict)
    error: str | None = None


class FileError(BaseModel):
    """A card file that could not be ingested, and why."""

    card: str
    path: str
    size: int
    mtime_ns: int
    message: str


class Manifest(BaseModel):
    """The campaign manifest (``manifest.json``)."""

    schema_version: int = SCHEMA_VERSION
    solidkit_version: str = ""
    conventions_version: int = 0
    grouping: GroupingParams = Field(default_factory=GroupingParams)
    response: dict[str, Any] = Field(default_factory=lambda: {"kind": "srgb_inverse"})
    lens_profile: dict[str, Any] | None = Field(
        None, description="per-unit lens profile overriding the model default: {kind: file, path, sha256} or {kind: shipped, name}"
    )
    vignetting: dict[str, Any] | None = Field(None, description="vignetting profile {kind: file, path, sha256}")
    cards: list[str] = Field(default_factory=list)
    shots: list[Shot] = Field(default_factory=list)
    scenes: list[Scene] = Field(default_factory=list)
    products: list[Product] = Field(default_factory=list)
    errors: list[FileError] = Field(default_factory=list)
    skipped: list[SourceRef] = Field(default_factory=list, description="unrelated files seen on the cards")

    def shot(self, sha: str) -> Shot:
        for s in self.shots:
            if s.sha256 == sha:
                return s
        raise KeyError(sha)


def load_manifest(campaign_dir: str | os.PathLike) -> Manifest:
    """Read and validate ``CAMPAIGN_DIR/manifest.json`` (an empty manifest when absent)."""
    from solidkit import __version__
    from solidkit.envmap.coords import CONVENTIONS_VERSION

    path = Path(campaign_dir) / MANIFEST_NAME
    if not path.exists():
        return Manifest(solidkit_version=__version__, conventions_version=CONVENTIONS_VERSION)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: unreadable manifest ({exc})") from None
    version = data.get("schema_version") if isinstance(data, dict) else None
    if version != SCHEMA_VERSION:
        raise InputError(f"{path}: manifest schema version {version!r}; this solidkit reads version {SCHEMA_VERSION}")
    try:
        return Manifest.model_validate(data)
    except Exception as exc:
        raise InputError(f"{path}: invalid manifest ({str(exc).splitlines()[0]})") from None


def _save_manifest(campaign: Path, manifest: Manifest) -> None:
    atomic_write_text(campaign / MANIFEST_NAME, manifest.model_dump_json(indent=1) + "\n")


# --------------------------------------------------------------------------- scanning
def scan_card(card: str | os.PathLike) -> tuple[list[Path], list[Path]]:
    """``(captures, unrelated)``: relative paths below ``card``, sorted (see module docstring)."""
    card = Path(card)
    if not card.is_dir():
        raise InputError(f"{card}: not a directory")
    captures, unrelated = [], []
    for root, dirs, files in os.walk(card):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(files):
            rel = Path(root, name).relative_to(card)
            if name.startswith(".") or Path(root, name).is_symlink():
                unrelated.append(rel)
            elif Path(name).suffix.lower() in IMAGE_SUFFIXES:
                captures.append(rel)
            else:
                unrelated.append(rel)
    return captures, unrelated


def _layout(rel: Path) -> tuple[str | None, str | None]:
    """(scene, probe-or-'photo') from the folder layout, or (None, None)."""
    parts = rel.parts[:-1]
    if not parts or parts[0].upper() == "DCIM" or _DCF.match(parts[0]):
        return None, None
    scene = parts[0]
    if len(parts) == 1 or parts[1].upper() == "DCIM" or _DCF.match(parts[1]):
        return scene, None
    return scene, ("photo" if parts[1].lower() == "photo" else parts[1])


# --------------------------------------------------------------------------- per-file worker
def _check_decodable(path: Path, fmt: str) -> None:
    """Decode the whole image (a truncated JPEG is an error, not a grey tail)."""
    if fmt == "jpeg":
        from PIL import Image

        try:
            with Image.open(path) as im:
                # DCT-domain 1/8 scaling: every entropy-coded byte is still decoded (truncation
                # and corrupt data are caught), at a fraction of the full decode's cost
                im.draft("RGB", (max(1, im.width // 8), max(1, im.height // 8)))
                im.load()
        except Exception as exc:
            raise InputError(f"cannot decode JPEG: truncated or corrupt ({type(exc).__name__}: {exc})") from None
    else:
        import rawpy

        try:
            with rawpy.imread(str(path)) as raw:
                raw.raw_image_visible.sum()
        except Exception as exc:
            raise InputError(f"cannot decode raw data ({type(exc).__name__}: {exc})") from None


def _copy_original(src: Path, dest: Path, sha: str) -> bool:
    """Copy ``src`` to ``dest`` atomically, verify its sha256, make it read-only. False if present."""
    if dest.exists():
        if dest.stat().st_size == src.stat().st_size:
            return False
        dest.chmod(stat.S_IWUSR | stat.S_IRUSR)  # a wrong-size file under a content name: replace it
        dest.unlink()
    with atomic_path(dest) as tmp:
        h = hashlib.sha256()
        with open(src, "rb") as fi, open(tmp, "wb") as fo:
            while block := fi.read(1 << 20):  # hash exactly the bytes written
                h.update(block)
                fo.write(block)
            fo.flush()
            os.fsync(fo.fileno())
        if h.hexdigest() != sha:
            raise InputError("copy verification failed: the file changed while it was being ingested")
        tmp.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
    return True


def _ingest_one(card: str, rel: str, campaign: str, throttle_s: float = 0.0) -> dict[str, Any]:
    """Worker: hash, validate, read metadata, copy. Returns ``{"shot": ...}`` or ``{"error": ...}``."""
    from solidkit.capture.merge import sniff_format
    from solidkit.camera.metadata import read_metadata

    src = Path(card) / rel
    st = src.stat()
    ref = {"card": card, "path": rel, "size": st.st_size, "mtime_ns": st.st_mtime_ns}
    try:
        if throttle_s:
            time.sleep(throttle_s)
        if st.st_size == 0:
            raise InputError("empty file (0 bytes)")
        kind = sniff_format(src)
        suffix = IMAGE_SUFFIXES[src.suffix.lower()]
        if suffix == ".jpg" and kind == "tiff":
            raise InputError(f"content is TIFF/DNG (raw) but the name ends in {src.suffix}; rename it to .dng")
        if suffix == ".jpg" and kind != "jpeg":
            raise InputError("not a JPEG file (bad signature)")
        if suffix == ".dng" and kind != "tiff":
            raise InputError("not a DNG file (no TIFF signature)")
        sha = sha256_file(src)
        meta = read_metadata(src)
        _check_decodable(src, "jpeg" if suffix == ".jpg" else "raw")
        original = Path("originals") / sha[:2] / f"{sha}{suffix}"
        copied = _copy_original(src, Path(campaign) / original, sha)
        md = meta.model_dump(mode="json")
        md["path"] = original.as_posix()
        return {
            "shot": {
                "sha256": sha, "original": original.as_posix(), "size": st.st_size, "file_format": md.get("file_format", "jpeg"),
                "sources": [ref], "metadata": md,
            },
            "copied": copied,
        }
    except SolidkitError as exc:
        return {"error": {**ref, "message": str(exc).replace(str(src) + ": ", "")}}
    except OSError as exc:
        return {"error": {**ref, "message": f"I/O error: {exc.strerror or exc}"}}


# --------------------------------------------------------------------------- grouping
def _time(shot: Shot) -> datetime | None:
    t = shot.metadata.get("datetime_original")
    if not t:
        return None
    try:
        return datetime.fromisoformat(str(t)).replace(tzinfo=None)
    except ValueError:
        return None


def _is_theta(shot: Shot) -> bool:
    if shot.layout_probe == "photo":
        return False
    if shot.layout_probe is not None:
        return True
    md = shot.metadata
    return md.get("image_type") in _THETA_TYPES or (md.get("make") or "").upper().startswith("RICOH")


def _exposure(shot: Shot) -> float | None:
    t = shot.metadata.get("exposure_time")
    return float(t) if t else None


def _end(shot: Shot) -> datetime | None:
    t = _time(shot)
    return None if t is None else t + timedelta(seconds=_exposure(shot) or 0.0)


def _order(shot: Shot) -> tuple:
    t = _time(shot)
    src = min((s.card, s.path) for s in shot.sources)
    return (t is None, t or datetime.min, src, shot.sha256)


def group_shots(manifest: Manifest) -> None:
    """(Re)compute scenes, probes, brackets and shot kinds from the shots (deterministic)."""
    from solidkit.capture.brackets import ShotInfo, gain_from, group_brackets, sequence_from_name

    g = manifest.grouping
    shots = sorted(manifest.shots, key=_order)
    for s in shots:
        s.kind = s.scene = s.probe = s.bracket = None
        first = min(s.sources, key=lambda r: (r.card, r.path))  # the same content twice: first source rules
        s.layout_scene, s.layout_probe = _layout(Path(first.path))
    scenes: dict[str, Scene] = {}
    probe_members: dict[tuple[str, str], list[Shot]] = {}

    # 1. scenes: folder scenes by name; the rest by time gaps (Theta shots and photos together)
    auto = [s for s in shots if s.layout_scene is None]
    for s in shots:
        if s.layout_scene is not None:
            sc = scenes.setdefault(s.layout_scene, Scene(id=s.layout_scene, grouping="folder"))
            s.scene = sc.id
    current: Scene | None = None
    last_end: datetime | None = None
    for s in auto:
        t = _time(s)
        if t is None:
            sc = scenes.setdefault("undated", Scene(id="undated", grouping="undated"))
            s.scene = sc.id
            continue
        if current is None or last_end is None or (t - last_end).total_seconds() > g.scene_gap_s:
            sid = "scene-" + t.strftime("%Y%m%d-%H%M%S")
            while sid in scenes:
                sid += "b"
            current = scenes.setdefault(sid, Scene(id=sid, grouping="time"))
            last_end = None
        s.scene = current.id
        end = _end(s)
        last_end = end if last_end is None or (end and end > last_end) else last_end

    # 2. probes within each scene; photos stay with the scene
    for sc in scenes.values():
        members = [s for s in shots if s.scene == sc.id]
        times = [t for t in (_time(s) for s in members) if t is not None]
        sc.start, sc.end = (min(times), max(times)) if times else (None, None)
        pid_auto = 0
        prev_end: datetime | None = None
        auto_probe: str | None = None
        for s in members:
            if not _is_theta(s):
                s.kind = "photo"
                sc.photos.append(s.sha256)
                continue
            if s.layout_probe is not None:
                s.probe = s.layout_probe
            else:
                t = _time(s)
                if auto_probe is None or t is None or prev_end is None or (t - prev_end).total_seconds() > g.probe_gap_s:
                    if not (t is None and auto_probe is not None):
                        pid_auto += 1
                        auto_probe = f"p{pid_auto:02d}"
                s.probe = auto_probe
                e = _end(s)
                prev_end = e if e is not None else prev_end
            probe_members.setdefault((sc.id, s.probe), []).append(s)

    # 3. brackets, kinds and the sun frame within each probe
    for (sid, pid), members in sorted(probe_members.items()):
        probe = Probe(id=pid, shots=[s.sha256 for s in members])
        infos = []
        for i, s in enumerate(members):
            md = s.metadata
            cam = " ".join(str(md.get(k) or "") for k in ("make", "model", "serial")).strip()
            name = min(src.path for src in s.sources)
            seq = md.get("sequence") if md.get("sequence") is not None else sequence_from_name(name)
            infos.append(ShotInfo(key=str(i), time=_time(s), sequence=seq, exposure=_exposure(s), camera=cam,
                                  size=(md.get("width"), md.get("height")), name=name,
                                  gain=gain_from(md.get("iso"), md.get("f_number"))))
        groups = group_brackets(infos, max_gap_s=g.bracket_gap_s)
        nb = 0
        prev_group: list[Shot] | None = None
        for grp in groups:
            gs = [members[int(x.key)] for x in grp]
            if prev_group is not None:
                _repeat_warning(prev_group, gs, g.bracket_gap_s, probe)
            prev_group = gs
            if len(gs) >= 2:
                nb += 1
                b = Bracket(id=f"b{nb:02d}", shots=[s.sha256 for s in gs], exposure_times=[_exposure(s) for s in gs])
                probe.brackets.append(b)
                for s in gs:
                    s.kind, s.bracket = "bracket_member", b.id
            else:
                s = gs[0]
                e = _exposure(s)
                s.kind = "low_exposure" if e is not None and e <= g.low_exposure_max_s else "probe"
        candidates = [s for s in members if s.kind == "low_exposure"] or [
            s for s in members if s.kind == "bracket_member" and (_exposure(s) or 1e9) <= g.low_exposure_max_s]
        if candidates:
            probe.sun_frame = min(candidates, key=lambda s: (_exposure(s) or 0.0, _order(s))).sha256
        scenes[sid].probes.append(probe)
    manifest.scenes = [scenes[k] for k in sorted(scenes, key=lambda k: (scenes[k].start is None, scenes[k].start or datetime.min, k))]
    manifest.shots = shots


def _repeat_warning(prev: list[Shot], cur: list[Shot], gap_s: float, probe: Probe) -> None:
    """Note brackets that were split only because an exposure repeated."""
    a, b = _end(prev[-1]), _time(cur[0])
    if a is None or b is None or (b - a).total_seconds() > gap_s:
        return
    from solidkit.capture.brackets import gain_from

    def eff(s: Shot) -> float | None:
        t = _exposure(s)
        return None if t is None else round(t * gain_from(s.metadata.get("iso"), s.metadata.get("f_number")), 12)

    if eff(cur[0]) is not None and eff(cur[0]) in {eff(s) for s in prev}:
        from solidkit.capture.brackets import format_exposure

        name = min(src.path for src in cur[0].sources)
        probe.warnings.append(
            f"duplicate_exposure: {name} repeats exposure {format_exposure(_exposure(cur[0]))} "
            f"{(b - a).total_seconds():.0f} s after the previous shot: started a new bracket")


# --------------------------------------------------------------------------- products
def _recipe_hash(recipe: dict[str, Any], inputs: list[str]) -> str:
    blob = json.dumps({"recipe": recipe, "inputs": inputs}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def planned_products(manifest: Manifest) -> list[Product]:
    """The products the grouping calls for (without their outputs)."""
    from solidkit import __version__

    out: list[Product] = []
    for sc in manifest.scenes:
        for pr in sc.probes:
            for b in pr.brackets:
                first = manifest.shot(b.shots[0]).metadata
                recipe = {"tool": "solidkit.capture.merge.merge_frames", "response": manifest.response,
                          "ghost_k": 6.0, "deghost": False, "wb": "camera", "solidkit_version": __version__,
                          **_unwarp_recipe(manifest, first)}
                out.append(Product(
                    id=f"{sc.id}/{pr.id}/hdr-{b.id}", kind="hdr", scene=sc.id, probe=pr.id, inputs=list(b.shots),
                    layout=first.get("image_type") or "unknown", exposure_time=first.get("exposure_time"),
                    f_number=first.get("f_number"), iso=first.get("iso"), recipe=recipe,
                    recipe_hash=_recipe_hash(recipe, list(b.shots)), solidkit_version=__version__))
            if pr.sun_frame:
                md = manifest.shot(pr.sun_frame).metadata
                recipe = {"tool": "solidkit.capture.campaign.sun_frame", "solidkit_version": __version__,
                          **_unwarp_recipe(manifest, md)}
                out.append(Product(
                    id=f"{sc.id}/{pr.id}/sun", kind="sun_frame", scene=sc.id, probe=pr.id, inputs=[pr.sun_frame],
                    layout=md.get("image_type") or "unknown", exposure_time=md.get("exposure_time"),
                    f_number=md.get("f_number"), iso=md.get("iso"), recipe=recipe,
                    recipe_hash=_recipe_hash(recipe, [pr.sun_frame]), solidkit_version=__version__))
    return out


def _unwarp_recipe(manifest: Manifest, md: dict[str, Any]) -> dict[str, Any]:
    """Recipe entries of a dual-fisheye product's unwarp: panorama height, lens/vignetting profiles
    (only those given; none for stitched captures, which they do not affect)."""
    if md.get("image_type") not in ("dual_fisheye", "dual_fisheye_upright"):
        return {}
    from solidkit.capture.unwarp import default_out_height

    out: dict[str, Any] = {"pano_height": default_out_height(int(md.get("width") or 0))}
    if manifest.lens_profile is not None:
        out["lens_profile"] = manifest.lens_profile
    if manifest.vignetting is not None:
        out["vignetting"] = manifest.vignetting
    return out


def _record_profile(campaign: Path, path: str | os.PathLike, prefix: str) -> dict[str, Any]:
    """Copy a profile file into ``CAMPAIGN_DIR/profiles/<prefix>-<sha16><suffix>`` (once); its record."""
    src = Path(path)
    sha = sha256_file(src)
    rel = Path("profiles") / f"{prefix}-{sha[:16]}{src.suffix.lower()}"
    if not (campaign / rel).exists():
        with atomic_path(campaign / rel) as tmp:
            shutil.copyfile(src, tmp)
    return {"kind": "file", "path": rel.as_posix(), "sha256": sha}


def _recorded_file(campaign: Path, record: dict[str, Any], what: str) -> Path:
    """The campaign's copy of a recorded profile, checked against its recorded sha256."""
    path = campaign / record["path"]
    if not path.is_file():
        raise InputError(f"{what} {record['path']} is missing from the campaign")
    if sha256_file(path) != record["sha256"]:
        raise InputError(f"{what} {record['path']} was modified (sha256 differs from the manifest)")
    return path


def _load_optics(campaign: Path, recipe: dict[str, Any]) -> tuple[Any, Any]:
    """``(lens profile or None, vignetting profile or None)`` of a product's recipe."""
    from solidkit.camera.lens import load_profile
    from solidkit.capture.unwarp import load_vignetting

    lens = vig = None
    rec = recipe.get("lens_profile")
    if rec is not None:
        lens = load_profile(rec["name"] if rec["kind"] == "shipped" else _recorded_file(campaign, rec, "lens profile"))
    rec = recipe.get("vignetting")
    if rec is not None:
        vig = load_vignetting(_recorded_file(campaign, rec, "vignetting profile"))
    return lens, vig


def _product_path(p: Product, suffix: str) -> Path:
    return Path("products") / p.scene / p.probe / f"{p.id.rsplit('/', 1)[-1]}{suffix}"


def _level_rotation(md: dict[str, Any]):
    """The metadata's levelling rotation (identity for upright dual-fisheye / corrected equirect)."""
    from solidkit.camera.metadata import CaptureMetadata, level_rotation

    meta = CaptureMetadata.model_validate(md)
    import numpy as np

    if meta.image_type == "dual_fisheye_upright":
        return np.eye(3)
    return np.asarray(level_rotation(meta))


def to_panorama(image, md: dict[str, Any], lens_profile: Any = None, vignetting: Any = None) -> tuple[Any, dict[str, Any]]:
    """A linear capture-layout image -> an equirect panorama in the panorama frame (conventions §2).

    Equirect: levelled by the metadata's gravity when the camera did not correct it (returned
    unchanged otherwise). Dual-fisheye: unwarped (:func:`solidkit.capture.unwarp.unwarp`) through
    ``lens_profile`` (a :class:`~solidkit.camera.lens.LensProfile`, e.g. a per-unit one) or else
    the shipped profile of the camera model, each lens divided by its falloff first when a
    ``vignetting`` profile is given, to the same size as ``solidkit capture unwarp`` makes by
    default (:func:`solidkit.capture.unwarp.default_out_height`: as wide as the input).
    Returns ``(panorama, info)``; raises :class:`InputError` when no profile fits or the layout
    is unknown.
    """
    import numpy as np

    layout = md.get("image_type")
    R = _level_rotation(md)
    identity = bool(np.allclose(R, np.eye(3), atol=1e-12))
    if layout == "equirect":
        if identity:
            return image, {"resampled": False}
        from solidkit.envmap.resample import rotate

        return rotate(image, R, "linear"), {"resampled": True, "levelled": True}
    if layout in ("dual_fisheye", "dual_fisheye_upright"):
        from solidkit.camera.lens import profile_for_metadata
        from solidkit.capture.unwarp import default_out_height, unwarp

        h, w = image.shape[:2]
        prof = lens_profile if lens_profile is not None else profile_for_metadata(md.get("model"), w, h)
        stats: dict[str, Any] = {}
        pano = unwarp(image, prof, default_out_height(w), R, stats=stats, vignetting=vignetting)
        return pano, {"resampled": True, "levelled": not identity, "profile": prof.model, "profile_key": prof.key(),
                      "vignetting": vignetting is not None, "seam_mad": stats.get("seam_mad")}
    raise InputError(f"image type {layout!r} is not a panorama layout (equirect or dual-fisheye)")


def _make_product(product: dict[str, Any], shots: list[dict[str, Any]], campaign: str, response: dict[str, Any]) -> dict[str, Any]:
    """Worker: build one product; returns the updated product dict (``error`` set on failure)."""
    p = Product.model_validate(product)
    camp = Path(campaign)
    try:
        if p.kind == "hdr":
            from solidkit.capture.merge import effective_exposure, load_frame, load_response, merge_frames
            from solidkit.envmap.io import write_exr

            resp = load_response(camp / response["path"]) if response.get("kind") == "file" else None
            ref = shots[0]["metadata"]
            frames, inputs = [], []
            for s in shots:
                md = s["metadata"]
                t = md.get("exposure_time")
                if not t:
                    raise InputError(f"{s['original']}: no exposure time in the metadata")
                eff = effective_exposure(t, md.get("iso"), md.get("f_number"), ref.get("iso"), ref.get("f_number"))
                frames.append(load_frame(camp / s["original"], eff, resp))
                inputs.append({"original": s["original"], "sha256": s["sha256"], "exposure_time": t, "effective_exposure": eff})
            result = merge_frames(frames, ghost_k=p.recipe["ghost_k"], deghost=p.recipe["deghost"])
            stats = result.stats()
            hdr, layout = result.hdr, p.layout
            lens, vig = _load_optics(camp, p.recipe)
            try:
                hdr, pano_info = to_panorama(hdr, ref, lens, vig)
                layout = "equirect"
            except SolidkitError as exc:  # no lens profile for this camera: keep the capture layout
                pano_info = {"panorama": f"not made: {exc}"}
            stats.update(pano_info)
            p.layout = layout
            rel = _product_path(p, ".exr")
            write_exr(camp / rel, hdr, {
                "exposure_time": ref.get("exposure_time"), "layout": p.layout,
                "units": "relative radiance: linear code per second at the first frame's ISO and f-number",
                "provenance": {"tool": p.recipe["tool"], "solidkit_version": p.solidkit_version, "inputs": inputs,
                               "response": response, "recipe": p.recipe, "stats": stats},
            })
            p.path, p.sha256, p.stats = rel.as_posix(), sha256_file(camp / rel), {
                k: (round(v, 6) if isinstance(v, float) else v) for k, v in stats.items() if k != "noise_sigma"}
        else:
            import numpy as np

            s = shots[0]
            md = s["metadata"]
            if (md.get("image_type") == "equirect" and s["original"].endswith(".jpg")
                    and np.allclose(_level_rotation(md), np.eye(3), atol=1e-12)):
                # the stitched, level JPEG is already the LDR panorama: referenced, not re-encoded
                p.path, p.sha256 = s["original"], s["sha256"]
                p.stats = {"resampled": False}
            else:
                from solidkit.capture.merge import load_frame
                from solidkit.envmap.io import write_ldr

                frame = load_frame(camp / s["original"], float(md.get("exposure_time") or 1.0))
                pano, info = to_panorama(frame.linear, md, *_load_optics(camp, p.recipe))
                rel = _product_path(p, ".png")
                write_ldr(camp / rel, np.clip(pano, 0.0, 1.0), encode_srgb=True)  # lossless 8-bit sRGB
                p.path, p.sha256, p.stats, p.layout = rel.as_posix(), sha256_file(camp / rel), info, "equirect"
    except SolidkitError as exc:
        p.error = str(exc)
        p.path = p.sha256 = None
    return p.model_dump(mode="json")


# --------------------------------------------------------------------------- the run
class IngestReport(BaseModel):
    """What one ingest run did (printed by the CLI; not stored)."""

    files_seen: int = 0
    copied: int = 0
    already_present: int = 0
    unchanged: int = 0
    new_sources: int = 0
    errors: list[FileError] = Field(default_factory=list)
    known_errors: int = 0
    unrelated: list[str] = Field(default_factory=list)
    products_built: int = 0
    products_up_to_date: int = 0
    products_removed: int = 0
    product_errors: list[str] = Field(default_factory=list)
    regrouped: bool = False

    @property
    def nothing_done(self) -> bool:
        return not (self.copied or self.new_sources or self.errors or self.products_built
                    or self.products_removed or self.regrouped or self.already_present)


@contextlib.contextmanager
def _lock(campaign: Path) -> Iterator[None]:
    campaign.mkdir(parents=True, exist_ok=True)
    fh = open(campaign / ".lock", "a+")
    try:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"{campaign}: another ingest is running on this campaign") from None
        yield
    finally:
        fh.close()


def _clean_temporaries(campaign: Path) -> int:
    """Remove temporaries of a killed run (hidden ``.name.xxxx`` files under originals/, products/)."""
    n = 0
    for sub in ("originals", "products"):
        root = campaign / sub
        if not root.is_dir():
            continue
        for dirpath, _, files in os.walk(root):
            for f in files:
                if f.startswith("."):
                    p = Path(dirpath, f)
                    p.chmod(stat.S_IRUSR | stat.S_IWUSR)
                    p.unlink(missing_ok=True)
                    n += 1
    for f in campaign.glob(f".{MANIFEST_NAME}.*"):
        f.unlink(missing_ok=True)
    return n


def _pool(jobs: int):
    if jobs <= 1:
        return None
    import multiprocessing as mp

    return ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn"))


def _run_tasks(fn: Callable, tasks: list[tuple], pool: ProcessPoolExecutor | None, on_result: Callable[[tuple, dict], None]) -> None:
    """Run ``fn(*task)`` for every task, inline (no pool) or in the process pool."""
    if pool is None:
        for t in tasks:
            on_result(t, fn(*t))
        return
    futures = {pool.submit(fn, *t): t for t in tasks}
    for fut in as_completed(futures):
        on_result(futures[fut], fut.result())


def ingest(
    card_dir: str | os.PathLike,
    campaign_dir: str | os.PathLike,
    *,
    jobs: int = 1,
    grouping: GroupingParams | dict[str, float] | None = None,
    response_path: str | os.PathLike | None = None,
    products: bool = True,
    progress: Any = None,
    lens_profile: str | os.PathLike | None = None,
    vignetting_path: str | os.PathLike | None = None,
) -> IngestReport:
    """Ingest one card into a campaign (see the module docstring). Returns what was done.

    ``response_path``, ``lens_profile`` (a per-unit lens profile JSON, or a shipped profile
    name, overriding the camera model's default) and ``vignetting_path`` (a vignetting profile
    JSON) are validated, recorded in the manifest (files copied into ``profiles/``) and used
    by this and later runs until replaced.

    ``progress(phase, done, total)`` (optional) is called as files and products complete.
    Raises :class:`InputError` for a missing card or an unreadable manifest; per-file problems
    are collected in the report and the manifest instead.
    """
    from solidkit import __version__
    from solidkit.envmap.coords import CONVENTIONS_VERSION

    card = Path(card_dir).resolve()
    campaign = Path(campaign_dir).resolve()
    if not card.is_dir():
        raise InputError(f"{card_dir}: card directory not found")
    if campaign == card or campaign.is_relative_to(card):
        raise InputError("the campaign directory must not be inside the card")
    if card.is_relative_to(campaign):
        raise InputError("the card must not be inside the campaign directory")
    if campaign.exists() and not campaign.is_dir():
        raise InputError(f"{campaign_dir}: exists and is not a directory")
    # validate everything before the campaign directory is created or touched
    for key, value in (grouping.model_dump() if isinstance(grouping, GroupingParams) else grouping or {}).items():
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"--{key.removesuffix('_s').replace('_', '-')} must be a positive number of seconds, got {value}")
    if response_path is not None:
        from solidkit.capture.merge import load_response

        load_response(Path(response_path))
    if lens_profile is not None:
        from solidkit.camera.lens import load_profile

        lp = load_profile(lens_profile)  # a file, or a shipped name
    if vignetting_path is not None:
        from solidkit.capture.unwarp import load_vignetting

        load_vignetting(vignetting_path)
    captures, unrelated = scan_card(card)
    if not captures:
        raise InputError(f"{card_dir}: no captures (.jpg/.jpeg/.dng) on this card")
    throttle = float(os.environ.get("SOLIDKIT_INGEST_THROTTLE_S", "0") or 0)  # testing aid: slow each file down
    report = IngestReport()
    with _lock(campaign), contextlib.ExitStack() as stack:
        pool = _pool(jobs)
        if pool is not None:
            stack.enter_context(pool)
        _clean_temporaries(campaign)
        manifest = load_manifest(campaign)
        before = manifest.model_dump_json()
        manifest.solidkit_version, manifest.conventions_version = __version__, CONVENTIONS_VERSION
        if isinstance(grouping, GroupingParams):
            manifest.grouping = grouping
        elif grouping:  # overrides of the campaign's stored parameters
            manifest.grouping = GroupingParams.model_validate({**manifest.grouping.model_dump(), **grouping})
        if response_path is not None:
            manifest.response = _record_profile(campaign, Path(response_path), "response")
        if lens_profile is not None:
            if Path(lens_profile).is_file():
                manifest.lens_profile = {**_record_profile(campaign, lens_profile, "lens"), "model": lp.model}
            else:
                manifest.lens_profile = {"kind": "shipped", "name": str(lens_profile), "key": lp.key()}
        if vignetting_path is not None:
            manifest.vignetting = _record_profile(campaign, vignetting_path, "vignetting")
        cstr = str(card)
        if cstr not in manifest.cards:
            manifest.cards = sorted([*manifest.cards, cstr])

        report.files_seen = len(captures)
        report.unrelated = [p.as_posix() for p in unrelated]
        # forget errors and skips of files that are no longer on this card
        present = {p.as_posix() for p in captures}
        manifest.errors = [e for e in manifest.errors if e.card != cstr or e.path in present]
        still_unrelated = {p.as_posix() for p in unrelated}
        manifest.skipped = [r for r in manifest.skipped if r.card != cstr or r.path in still_unrelated]
        known_skips = {(s.card, s.path) for s in manifest.skipped}
        for p in unrelated:
            if (cstr, p.as_posix()) not in known_skips:
                st = (card / p).lstat()
                manifest.skipped.append(SourceRef(card=cstr, path=p.as_posix(), size=st.st_size, mtime_ns=st.st_mtime_ns))
        manifest.skipped.sort(key=lambda r: (r.card, r.path))

        by_source = {(r.card, r.path, r.size, r.mtime_ns): s for s in manifest.shots for r in s.sources}
        bad = {(e.card, e.path, e.size, e.mtime_ns) for e in manifest.errors}
        todo: list[tuple] = []
        for rel in captures:
            st = (card / rel).stat()
            key = (cstr, rel.as_posix(), st.st_size, st.st_mtime_ns)
            if key in by_source:
                report.unchanged += 1
            elif key in bad:
                report.known_errors += 1
            else:
                todo.append((cstr, rel.as_posix(), str(campaign), throttle))

        shots_by_sha = {s.sha256: s for s in manifest.shots}
        last_save = [time.monotonic()]
        done = [0]

        def on_file(task: tuple, res: dict) -> None:
            done[0] += 1
            _, relpath, _, _ = task
            # a file re-ingested (changed, or fixed after an error) replaces its stale records
            manifest.errors[:] = [e for e in manifest.errors if (e.card, e.path) != (cstr, relpath)]
            for s in manifest.shots:
                s.sources = [r for r in s.sources if (r.card, r.path) != (cstr, relpath)]
            if "error" in res:
                fe = FileError.model_validate(res["error"])
                manifest.errors.append(fe)
                report.errors.append(fe)
            else:
                shot = Shot.model_validate(res["shot"])
                if shot.sha256 in shots_by_sha:
                    existing = shots_by_sha[shot.sha256]
                    existing.sources = sorted([*existing.sources, *shot.sources], key=lambda r: (r.card, r.path))
                    report.new_sources += 1
                else:
                    manifest.shots.append(shot)
                    shots_by_sha[shot.sha256] = shot
                    if res.get("copied"):
                        report.copied += 1
                    else:
                        report.already_present += 1
            if progress is not None:
                progress("files", done[0], len(todo))
            if time.monotonic() - last_save[0] > 1.0:
                manifest.shots[:] = [s for s in manifest.shots if s.sources]
                _save_manifest(campaign, manifest)
                last_save[0] = time.monotonic()

        if progress is not None:
            progress("files", 0, len(todo))
        _run_tasks(_ingest_one, todo, pool, on_file)
        manifest.shots[:] = [s for s in manifest.shots if s.sources]
        manifest.errors.sort(key=lambda e: (e.card, e.path))
        for s in manifest.shots:
            s.sources.sort(key=lambda r: (r.card, r.path))
        old_groups = json.dumps([s.model_dump(mode="json") for s in manifest.scenes], sort_keys=True)
        group_shots(manifest)
        report.regrouped = bool(todo) and old_groups != json.dumps(
            [s.model_dump(mode="json") for s in manifest.scenes], sort_keys=True)
        if manifest.model_dump_json() != before:
            _save_manifest(campaign, manifest)

        if products:
            _build_products(manifest, campaign, pool, report, progress)
        manifest.products.sort(key=lambda p: p.id)
        if manifest.model_dump_json() != before:
            _save_manifest(campaign, manifest)
    return report


def _build_products(manifest: Manifest, campaign: Path, pool: ProcessPoolExecutor | None, report: IngestReport, progress: Any) -> None:
    wanted = planned_products(manifest)
    existing = {p.id: p for p in manifest.products}
    keep: list[Product] = []
    tasks: list[tuple] = []
    for p in wanted:
        old = existing.get(p.id)
        if old is not None and old.recipe_hash == p.recipe_hash and (
            old.error is not None or (old.path and (campaign / old.path).is_file()
                                      and (old.path.startswith("originals/") or sha256_file(campaign / old.path) == old.sha256))):
            keep.append(old)
            report.products_up_to_date += 1
            if old.error:
                report.product_errors.append(f"{old.id}: {old.error}")
            continue
        shots = [manifest.shot(sha).model_dump(mode="json") for sha in p.inputs]
        tasks.append((p.model_dump(mode="json"), shots, str(campaign), manifest.response))
    wanted_ids = {p.id for p in wanted}
    for pid, old in existing.items():
        if pid not in wanted_ids:
            report.products_removed += 1
            if old.path and old.path.startswith("products/"):
                (campaign / old.path).unlink(missing_ok=True)
    results: list[Product] = list(keep)
    done = [0]

    def on_product(task: tuple, res: dict) -> None:
        prod = Product.model_validate(res)
        results.append(prod)
        report.products_built += 1
        if prod.error:
            report.product_errors.append(f"{prod.id}: {prod.error}")
        done[0] += 1
        if progress is not None:
            progress("products", done[0], len(tasks))
        manifest.products = sorted(results, key=lambda p: p.id)
        _save_manifest(campaign, manifest)

    if tasks:
        if progress is not None:
            progress("products", 0, len(tasks))
        _run_tasks(_make_product, tasks, pool, on_product)
    manifest.products = sorted(results, key=lambda p: p.id)


def summary_rows(manifest: Manifest) -> list[tuple[str, str]]:
    """(label, value) rows describing a campaign, for reports."""
    kinds: dict[str, int] = {}
    for s in manifest.shots:
        kinds[s.kind or "?"] = kinds.get(s.kind or "?", 0) + 1
    n_probes = sum(len(sc.probes) for sc in manifest.scenes)
    n_brackets = sum(len(p.brackets) for sc in manifest.scenes for p in sc.probes)
    return [
        ("shots", f"{len(manifest.shots)} ({', '.join(f'{v} {k}' for k, v in sorted(kinds.items()))})"),
        ("scenes / probes / brackets", f"{len(manifest.scenes)} / {n_probes} / {n_brackets}"),
        ("products", f"{len(manifest.products)} ({sum(1 for p in manifest.products if p.error)} with errors)"),
        ("profiles", "; ".join(f"{name} {_describe(rec, default)}" for name, rec, default in (
            ("response", manifest.response, "sRGB inverse"), ("lens", manifest.lens_profile, "model default"),
            ("vignetting", manifest.vignetting, "none")))),
    ]


def _describe(record: dict[str, Any] | None, default: str) -> str:
    if not record or record.get("kind") not in ("file", "shipped"):
        return default
    return record["name"] if record["kind"] == "shipped" else record["path"]
