"""Grouping a campaign's shots into scenes, Theta positions (probes) and brackets; applying the field notes.

Two card layouts are understood, per file (:func:`solidkit.capture.card.folder_layout`):

1. **Explicit** (recommended; the field protocol and the synthetic campaign use it)::

       CARD_DIR/<scene>/photo/<name>.jpg          the scene's normal photo(s)      -> kind "photo"
       CARD_DIR/<scene>/<probe>/<name>.jpg|.dng   Theta shots at position <probe> (``cam``: the photo camera's)
       CARD_DIR/<scene>/<name>.jpg|.dng           Theta shots of <scene>; positions split by time
       CARD_DIR/<scene>/fieldnotes.toml           the field notes (:mod:`solidkit.capture.fieldnotes`)

   ``<scene>``/``<probe>`` folder names are the ids (deeper sub-folders are allowed and ignored).
   A first-level folder named ``DCIM`` or shaped like a DCF folder (``100RICOH``) is not a scene.

2. **Automatic** (a camera's own ``DCIM/100RICOH/R0010001.JPG`` card): by capture time (EXIF
   ``DateTimeOriginal``, camera clock; keep the cameras' clocks set). Shots of the whole campaign
   are sorted by time; a gap above ``scene_gap_s`` (default 600 s) starts a new scene
   (``scene-YYYYMMDD-HHMMSS`` of its first shot); within a scene positions (``p01``, ``p02``, ...)
   are split by the scene's own shooting rhythm (:func:`position_starts`; gaps from the end of
   one Theta shot to the next), or at every gap above ``probe_gap_s`` when it is set to another
   value than its default 45 s (``ingest --probe-gap``). Shots without a timestamp go to scene
   ``undated``, probe ``p01``. A non-Theta image (not a Ricoh equirect/dual-fisheye capture) is a
   **photo**; it joins the scene whose time span (± ``scene_gap_s``) contains it, so a photo
   camera's card can be ingested after the Theta's card into the same campaign.

Within a position, Theta shots are grouped into brackets (:mod:`solidkit.capture.bracket_groups`:
time gaps <= ``bracket_gap_s``, distinct exposures). Kinds: ``bracket_member`` (a group of two
or more), ``low_exposure`` (a single shot at <= ``low_exposure_max_s``, default 1/4000 s: the sun
frame), ``probe`` (any other single shot), ``photo``. A position that gets no HDR product (no
bracket) or no sun frame (nothing at or below ``low_exposure_max_s``) carries a ``no_hdr:`` /
``no_sun_frame:`` warning saying why.

Field notes (:func:`apply_notes`): the scene's notes file (or its table in a card-level file)
names the camera position, the reference photo, each probe's photo pixel and remarks, and
optionally the photo camera's pose. Without notes, a position folder named ``cam``/``camera``
is the camera position. The photo's heading comes from its EXIF ``GPSImgDirection`` and its
pitch/roll from its metadata (GPano pose) where recorded, else from the notes' ``photo_pose``;
``Scene.photo_pose_source`` says which.
"""

from __future__ import annotations

from datetime import datetime, timedelta
from pathlib import Path
from typing import Any, cast

from solidkit.capture.bracket_groups import ShotInfo, format_exposure, gain_from, group_brackets, sequence_from_name
from solidkit.capture.card import folder_layout
from solidkit.capture.fieldnotes import CAMERA_FOLDERS, CardNotes, FieldNotes
from solidkit.capture.manifest import Bracket, GroupingParams, Manifest, Probe, Scene, Shot

__all__ = ["group_shots", "apply_notes", "shot_time", "position_starts", "RHYTHM_PROBE_GAP_S"]

_THETA_TYPES = {"equirect", "dual_fisheye", "dual_fisheye_upright"}


def shot_time(shot: Shot) -> datetime | None:
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
    t = shot_time(shot)
    return None if t is None else t + timedelta(seconds=_exposure(shot) or 0.0)


def _order(shot: Shot) -> tuple:
    t = shot_time(shot)
    src = min((s.card, s.path) for s in shot.sources)
    return (t is None, t or datetime.min, src, shot.sha256)


#: ``probe_gap_s`` at this value (the default) splits positions by the shooting rhythm; any other value is a fixed gap.
RHYTHM_PROBE_GAP_S = GroupingParams().probe_gap_s


def _same_exposure(a: float, b: float) -> bool:
    return abs(a - b) <= 0.02 * max(a, b)


def position_starts(shots: list[Shot], g: GroupingParams) -> set[int]:
    """Indices of the shots (one scene's Theta shots without a position folder, in time order) that start a
    new position after the previous timed one: splits that adapt to the scene's shooting rhythm.

    The gaps (from the end of one shot to the next one's start) longer than ``bracket_gap_s`` are the
    candidates (a shorter one keeps a bracket together). Where they fall into two groups (the largest ratio
    between two of them in size order at least 2: pauses within a position, e.g. before a sun frame, and moves
    between positions) the threshold is the geometric mean of that pair; where they form one group it is
    ``probe_gap_s``. A candidate gap starts a new position when it exceeds the threshold or when the next shot's
    exposure time repeats one already shot since the position began (a bracket starting over: a team faster than
    the threshold). A team that moves every 25 s with 1 s shots and one that pauses a minute before each sun
    frame and moves every 3 minutes are both split right (a fixed 45 s merges the first's positions and splits
    the second's). A bracket shot again at the same spot after a pause reads as a new position (name the
    positions by folder or in the field notes). ``probe_gap_s`` other than its default
    (:data:`RHYTHM_PROBE_GAP_S`): every gap above it, and only those, starts a new position.
    """
    gaps: dict[int, float] = {}
    prev_end: datetime | None = None
    for i, s in enumerate(shots):
        t = shot_time(s)
        if t is not None and prev_end is not None:
            gaps[i] = (t - prev_end).total_seconds()
        e = _end(s)
        prev_end = e if e is not None else prev_end
    if g.probe_gap_s != RHYTHM_PROBE_GAP_S:
        return {i for i, gap in gaps.items() if gap > g.probe_gap_s}
    cand = sorted(gap for gap in gaps.values() if gap > g.bracket_gap_s)
    threshold = g.probe_gap_s
    if len(cand) >= 2:
        ratio, k = max((cand[j + 1] / cand[j], j) for j in range(len(cand) - 1))
        if ratio >= 2.0:
            threshold = (cand[k] * cand[k + 1]) ** 0.5
    starts: set[int] = set()
    seen: list[float] = []
    for i, s in enumerate(shots):
        exp = _exposure(s)
        gap = gaps.get(i)
        if gap is not None and gap > g.bracket_gap_s:
            if gap > threshold or (exp is not None and any(_same_exposure(exp, x) for x in seen)):
                starts.add(i)
                seen = []
        if exp is not None:
            seen.append(exp)
    return starts


def group_shots(manifest: Manifest) -> None:
    """(Re)compute scenes, probes, brackets and shot kinds from the shots (deterministic)."""
    g = manifest.grouping
    shots = sorted(manifest.shots, key=_order)
    for s in shots:
        s.kind = s.scene = s.probe = s.bracket = None
        first = min(s.sources, key=lambda r: (r.card, r.path))  # the same content twice: first source rules
        s.layout_scene, s.layout_probe = folder_layout(Path(first.path))
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
        t = shot_time(s)
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
        times = [t for t in (shot_time(s) for s in members) if t is not None]
        sc.start, sc.end = (min(times), max(times)) if times else (None, None)
        pid_auto = 0
        timed = False  # a timed auto-position shot came before
        auto_probe: str | None = None
        auto = [s for s in members if _is_theta(s) and s.layout_probe is None]
        starts = {auto[i].sha256 for i in position_starts(auto, g)}
        for s in members:
            if not _is_theta(s):
                s.kind = "photo"
                sc.photos.append(s.sha256)
                continue
            if s.layout_probe is not None:
                s.probe = s.layout_probe
            else:
                t = shot_time(s)
                if auto_probe is None or (t is not None and (not timed or s.sha256 in starts)):
                    pid_auto += 1
                    auto_probe = f"p{pid_auto:02d}"
                s.probe = auto_probe
                timed = timed or _end(s) is not None
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
            infos.append(
                ShotInfo(
                    key=str(i),
                    time=shot_time(s),
                    sequence=seq,
                    exposure=_exposure(s),
                    camera=cam,
                    size=(md.get("width"), md.get("height")),
                    name=name,
                    gain=gain_from(md.get("iso"), md.get("f_number")),
                )
            )
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
                exposure = _exposure(s)
                s.kind = "low_exposure" if exposure is not None and exposure <= g.low_exposure_max_s else "probe"
        candidates = [s for s in members if s.kind == "low_exposure"] or [
            s for s in members if s.kind == "bracket_member" and (_exposure(s) or 1e9) <= g.low_exposure_max_s
        ]
        if candidates:
            probe.sun_frame = min(candidates, key=lambda s: (_exposure(s) or 0.0, _order(s))).sha256
        _availability_warnings(probe, members, g)
        scenes[sid].probes.append(probe)
    manifest.scenes = [
        scenes[k] for k in sorted(scenes, key=lambda k: (scenes[k].start is None, scenes[k].start or datetime.min, k))
    ]
    manifest.shots = shots
    for sc in manifest.scenes:
        apply_notes(sc, manifest)


def _repeat_warning(prev: list[Shot], cur: list[Shot], gap_s: float, probe: Probe) -> None:
    """Note brackets that were split only because an exposure repeated."""
    a, b = _end(prev[-1]), shot_time(cur[0])
    if a is None or b is None or (b - a).total_seconds() > gap_s:
        return

    def eff(s: Shot) -> float | None:
        t = _exposure(s)
        return None if t is None else round(t * gain_from(s.metadata.get("iso"), s.metadata.get("f_number")), 12)

    if eff(cur[0]) is not None and eff(cur[0]) in {eff(s) for s in prev}:
        name = min(src.path for src in cur[0].sources)
        probe.warnings.append(
            f"duplicate_exposure: {name} repeats exposure {format_exposure(_exposure(cur[0]))} "
            f"{(b - a).total_seconds():.0f} s after the previous shot: started a new bracket"
        )


def _availability_warnings(probe: Probe, members: list[Shot], g: GroupingParams) -> None:
    """Say why a position gets no HDR product (no bracket) or no sun frame."""
    exposures = [_exposure(s) for s in members]
    listed = ", ".join(format_exposure(e) for e in exposures[:8]) + (" ..." if len(exposures) > 8 else "")
    if not probe.brackets:
        if len(members) == 1:
            why = f"a single shot ({listed}); an HDR product needs a bracket of 2+ exposures"
        elif any(e is None for e in exposures):
            why = f"{len(members)} shots, some without an exposure time in their metadata"
        else:
            times = [shot_time(s) for s in members]
            gaps = [
                (tb - cast(datetime, _end(a))).total_seconds()
                for a, ta, tb in zip(members, times, times[1:])
                if ta is not None and tb is not None
            ]
            gap_text = f"; gaps {', '.join(f'{x:.0f} s' for x in gaps[:8])}" if gaps else ""
            why = (
                f"{len(members)} shots ({listed}) but no two distinct exposures within bracket_gap_s "
                f"({g.bracket_gap_s:g} s) of each other{gap_text}"
            )
        probe.warnings.append(f"no_hdr: {why}")
    if probe.sun_frame is None:
        known = [e for e in exposures if e is not None]
        if not known:
            why = "no shot records an exposure time"
        else:
            why = (
                f"the shortest exposure, {format_exposure(min(known))}, is longer than low_exposure_max_s "
                f"({format_exposure(g.low_exposure_max_s)}); the sun disk needs a low-exposure frame"
            )
        probe.warnings.append(f"no_sun_frame: {why}")


def _scene_notes(scene: Scene, manifest: Manifest) -> tuple[FieldNotes | None, str | None]:
    """The field notes that apply to ``scene`` and their file's sha256 (scene file first, then card-level)."""
    found: list[tuple[int, str, str, FieldNotes, str]] = []
    for rec in manifest.fieldnotes:
        if rec.error is not None:
            if rec.scene == scene.id:
                scene.warnings.append(f"fieldnotes_invalid: {rec.error} (nothing of it was applied)")
            continue
        if rec.notes is None:
            continue
        if rec.scene == scene.id:
            found.append((0, rec.card, rec.path, FieldNotes.model_validate(rec.notes), rec.sha256))
        elif rec.scene is None:
            card_notes = CardNotes.model_validate(rec.notes)
            if scene.id in card_notes.scenes:
                found.append((1, rec.card, rec.path, card_notes.scenes[scene.id], rec.sha256))
    if not found:
        return None, None
    found.sort(key=lambda f: f[:3])
    if len(found) > 1:
        scene.warnings.append(
            f"fieldnotes_several: {len(found)} field notes files cover this scene; used {found[0][2]} ({found[0][1]})"
        )
    return found[0][3], found[0][4]


def _source_name(shot: Shot) -> str:
    return min(shot.sources, key=lambda r: (r.card, r.path)).path


def apply_notes(scene: Scene, manifest: Manifest) -> None:
    """Set the scene's reference photo, camera position, probe roles/pixels/notes and photo pose.

    From the field notes that apply to the scene (module docstring); problems (a probe or photo
    the notes name but the card lacks, a pixel outside the photo, probes without a pixel) become
    warnings of the scene or the probe.
    """
    notes, sha = _scene_notes(scene, manifest)
    scene.fieldnotes, scene.notes = sha, notes.notes if notes else None
    probes = {p.id: p for p in scene.probes}
    # the reference photo
    photos = [manifest.shot(s) for s in scene.photos]
    scene.photo = photos[0].sha256 if photos else None
    if notes is not None and notes.photo:
        want = notes.photo.lower()
        match = [
            s for s in photos if any(Path(r.path).name.lower() == want or r.path.lower() == want for r in s.sources)
        ]
        if match:
            scene.photo = match[0].sha256
        else:
            scene.warnings.append(
                f"fieldnotes_photo_missing: the notes name photo {notes.photo!r}, not found "
                f"among the scene's {len(photos)} photo(s)"
            )
    elif len(photos) > 1:
        scene.warnings.append(
            f"several_photos: {len(photos)} photos and no field notes naming one; "
            f"probe pixels and pose refer to {_source_name(photos[0])}"
        )
    if scene.photo is not None:  # the photo's clock against its own GPS time (camera.metadata)
        ref = manifest.shot(scene.photo)
        scene.warnings += [
            f"clock_mismatch: photo {_source_name(ref)}: {w.split(': ', 1)[1]}"
            for w in ref.metadata.get("warnings", [])
            if w.startswith("clock_mismatch: ")
        ]
    # the camera position
    scene.camera_probe = None
    if notes is not None and notes.camera_position is not None:
        if notes.camera_position in probes:
            scene.camera_probe = notes.camera_position
        else:
            scene.warnings.append(
                f"fieldnotes_unknown_probe: camera_position {notes.camera_position!r} has no Theta shots on the card"
            )
    else:
        named = [p.id for p in scene.probes if p.id.lower() in CAMERA_FOLDERS]
        if named:
            scene.camera_probe = named[0]
        else:
            scene.warnings.append(
                "no_camera_position: neither field notes nor a 'cam' folder mark the Theta position at the photo camera"
            )
    for p in scene.probes:
        p.role = "camera" if p.id == scene.camera_probe else "probe"
        p.photo_pixel = p.note = None
    # per-probe notes
    size = None
    if scene.photo is not None:
        md = manifest.shot(scene.photo).metadata
        size = (md.get("width"), md.get("height"))
    if notes is not None:
        for pid, pn in notes.probes.items():
            if pid not in probes:
                scene.warnings.append(
                    f"fieldnotes_unknown_probe: notes for {pid!r}, which has no Theta shots on the card"
                )
                continue
            pr = probes[pid]
            pr.note = pn.note
            if pn.pixel is not None:
                pr.photo_pixel = [float(pn.pixel[0]), float(pn.pixel[1])]
                if size and size[0] and size[1] and not (pn.pixel[0] <= size[0] and pn.pixel[1] <= size[1]):
                    pr.warnings.append(
                        f"photo_pixel_outside: [{pn.pixel[0]:g}, {pn.pixel[1]:g}] lies outside the "
                        f"{size[0]}x{size[1]} photo"
                    )
        for pr in scene.probes:
            if pr.role == "probe" and pr.photo_pixel is None:
                pr.warnings.append("no_photo_pixel: the field notes give no photo pixel for this position")
    elif any(p.role == "probe" for p in scene.probes):
        scene.warnings.append(
            "no_fieldnotes: no field notes for this scene: probe photo pixels unknown (mark them in the labeling app)"
        )
    _photo_pose(scene, manifest, notes)


def _photo_pose(scene: Scene, manifest: Manifest, notes: FieldNotes | None) -> None:
    """Heading, pitch and roll of the reference photo: its metadata first, then the notes' photo_pose."""
    scene.photo_heading_deg = scene.photo_heading_ref = scene.photo_pitch_deg = scene.photo_roll_deg = None
    scene.photo_pose_source = {}
    md: dict[str, Any] = manifest.shot(scene.photo).metadata if scene.photo else {}
    gps = md.get("gps") or {}
    if gps.get("img_direction_deg") is not None:
        scene.photo_heading_deg = float(gps["img_direction_deg"])
        scene.photo_heading_ref = "magnetic" if gps.get("img_direction_ref") == "M" else "true"
        scene.photo_pose_source["heading"] = "exif:GPSImgDirection"
    if md.get("pitch_deg") is not None and md.get("roll_deg") is not None:
        scene.photo_pitch_deg, scene.photo_roll_deg = float(md["pitch_deg"]), float(md["roll_deg"])
        src = f"metadata:{md.get('gravity_source') or 'pose'}"
        scene.photo_pose_source.update(pitch=src, roll=src)
    pose = notes.photo_pose if notes is not None else None
    if pose is None:
        return
    if scene.photo_heading_deg is None and pose.heading_deg is not None:
        scene.photo_heading_deg, scene.photo_heading_ref = pose.heading_deg, pose.heading_ref
        scene.photo_pose_source["heading"] = "fieldnotes"
    if scene.photo_pitch_deg is None and pose.pitch_deg is not None:
        scene.photo_pitch_deg = pose.pitch_deg
        scene.photo_pose_source["pitch"] = "fieldnotes"
    if scene.photo_roll_deg is None and pose.roll_deg is not None:
        scene.photo_roll_deg = pose.roll_deg
        scene.photo_pose_source["roll"] = "fieldnotes"
