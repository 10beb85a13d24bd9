"""Croissant 1.1 metadata (JSON-LD) of an exported test set, with per-file radiometry as ``solidkit:`` properties.

The export folder (:mod:`solidkit.testset.publish`) holds the test set under ``data/`` and two
record tables under ``records/``; the metadata describes them:

- ``distribution``: ``data/testset.json``, ``records/scenes.csv``, ``records/probes.csv``
  (FileObjects with SHA-256), FileSets of the 320x240 photos, the LDR probes and the saturation
  masks, and one FileObject per HDR file (``hdr.exr``, ``hdr_full.exr`` of every probe and
  camera capture) carrying its units and clipping;
- ``recordSet``: ``scenes`` (one record per scene: capture, intrinsics, pose, the sun label with
  its uncertainty and provenance), ``probes`` (one per probe: pixel, files, rotation residual,
  provenance) and ``photos`` (the 320x240 photo images).

Extension vocabulary (``solidkit:`` = :data:`SOLIDKIT_NS`; docs/dataset-export.md): on each HDR
FileObject ``solidkit:radianceUnit`` (text), ``solidkit:colourEncoding``, ``solidkit:frame``,
``solidkit:capture`` (``scene/capture``), ``solidkit:bracketExposureTimes`` (seconds),
``solidkit:referenceIso``, ``solidkit:referenceFNumber``, ``solidkit:responseCurve``,
``solidkit:clippedFraction`` (share of pixels saturated in every frame of the bracket, from the
campaign's merge; absent when the campaign was not given) and ``solidkit:clippedFractionScope``;
on the dataset ``solidkit:datasetVersion`` (the content hash) and ``solidkit:openQuestions``
(what only the team can answer).
"""

from __future__ import annotations

from typing import Any

from solidkit.testset.facts import HDR_UNITS, TODO, CampaignFacts, ExportInfo, hdr_files
from solidkit.testset.schema import TestSet

__all__ = ["CONFORMS_TO", "SOLIDKIT_NS", "SCENE_COLUMNS", "PROBE_COLUMNS", "records", "croissant_metadata"]

CONFORMS_TO = "http://mlcommons.org/croissant/1.1"
SOLIDKIT_NS = "https://solidkit/ns/dataset#"
DATA = "data"

#: (column, Croissant data type, description) of records/scenes.csv
SCENE_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("scene_id", "sc:Text", "scene id"),
    ("photo", "sc:Text", "path of the 320x240 sRGB photo (model input), relative to the metadata file"),
    ("time_local", "sc:Text", "EXIF DateTimeOriginal of the photo, camera clock, ISO 8601 without offset"),
    ("utc_offset", "sc:Text", "EXIF OffsetTimeOriginal"),
    ("lat_deg", "sc:Float", "photo GPS latitude, degrees"),
    ("lon_deg", "sc:Float", "photo GPS longitude, degrees"),
    ("camera", "sc:Text", "photo camera make and model (EXIF)"),
    ("fx", "sc:Float", "focal length of the 320x240 photo, pixels"),
    ("fy", "sc:Float", "focal length of the 320x240 photo, pixels"),
    ("cx", "sc:Float", "principal point x, pixels (OpenCV pixel centres)"),
    ("cy", "sc:Float", "principal point y, pixels"),
    ("intrinsics_source", "sc:Text", "where K came from"),
    ("pitch_deg", "sc:Float", "photo camera pitch in its panorama frame (docs/conventions.md section 4)"),
    ("roll_deg", "sc:Float", "photo camera roll, degrees"),
    ("sun_found", "sc:Boolean", "whether a sun is labeled (false: overcast, occluded)"),
    ("sun_azimuth_deg", "sc:Float", "sun azimuth in the photo's panorama frame: 0 forward, positive right"),
    ("sun_elevation_deg", "sc:Float", "sun elevation above the horizon, degrees"),
    ("sun_uncertainty_deg", "sc:Float", "1-sigma angular uncertainty of the sun label, degrees"),
    ("sun_source", "sc:Text", "who set the sun label: auto, field_notes, annotator or reviewed"),
    ("probes", "sc:Integer", "number of probes"),
    ("flags", "sc:Text", "open problems, '; '-separated"),
)
#: (column, Croissant data type, description) of records/probes.csv
PROBE_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("scene_id", "sc:Text", "scene id (scenes.scene_id)"),
    ("probe_id", "sc:Text", "probe id within the scene"),
    ("x", "sc:Float", "probe pixel x in the 320x240 photo (OpenCV pixel centres)"),
    ("y", "sc:Float", "probe pixel y in the 320x240 photo"),
    ("pixel_source", "sc:Text", "who set the pixel: auto, field_notes, annotator or reviewed"),
    ("ldr", "sc:Text", "path of the 256x128 sRGB LDR probe (photo panorama frame)"),
    ("hdr", "sc:Text", "path of the 256x128 linear HDR probe (EXR), empty without a bracket"),
    ("saturation", "sc:Text", "path of the 256x128 mask: 255 where the LDR probe is clipped"),
    ("ldr_clipped_fraction", "sc:Float", "solid-angle-weighted share of clipped LDR pixels"),
    ("rotation_source", "sc:Text", "who set the probe's rotation into the panorama frame"),
    ("rotation_residual_deg", "sc:Float", "disagreement of the alignment cues with the chosen rotation, degrees"),
    ("ldr_exposure_time_s", "sc:Float", "exposure time of the shot the LDR probe is made from, seconds"),
    ("flags", "sc:Text", "open problems, '; '-separated"),
)


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def records(ts: TestSet) -> tuple[list[list[str]], list[list[str]]]:
    """Rows (strings, header first) of ``records/scenes.csv`` and ``records/probes.csv``."""
    scenes = [[c for c, _, _ in SCENE_COLUMNS]]
    probes = [[c for c, _, _ in PROBE_COLUMNS]]
    for s in ts.scenes:
        cap, sun = s.capture, s.sun
        camera = " ".join(x for x in (cap.make, cap.model) if x) or None
        row = [
            s.id,
            f"{DATA}/{s.photo}",
            cap.time_local,
            cap.utc_offset,
            cap.gps.lat_deg if cap.gps else None,
            cap.gps.lon_deg if cap.gps else None,
            camera,
            s.K[0][0],
            s.K[1][1],
            s.K[0][2],
            s.K[1][2],
            s.K_source,
            s.pitch_deg,
            s.roll_deg,
            sun.found,
            sun.azimuth_deg,
            sun.elevation_deg,
            sun.uncertainty_deg,
            sun.source,
            len(s.probes),
            "; ".join(s.flags + sun.flags),
        ]
        scenes.append([_cell(v) for v in row])
        for p in s.probes:
            ldr_t = p.capture.ldr_exposure.exposure_time_s if p.capture.ldr_exposure else None
            row = [
                s.id,
                p.id,
                p.pixel[0],
                p.pixel[1],
                p.pixel_source,
                f"{DATA}/{p.ldr}",
                f"{DATA}/{p.hdr}" if p.hdr else "",
                f"{DATA}/{p.images.saturation}",
                p.images.saturated_fraction,
                p.alignment.source,
                p.alignment.residual_deg,
                ldr_t,
                "; ".join(p.flags),
            ]
            probes.append([_cell(v) for v in row])
    return scenes, probes


def _fields(record_set: str, file_id: str, columns: tuple[tuple[str, str, str], ...]) -> list[dict[str, Any]]:
    return [
        {
            "@type": "cr:Field",
            "@id": f"{record_set}/{name}",
            "name": name,
            "description": text,
            "dataType": dtype,
            "source": {"fileObject": {"@id": file_id}, "extract": {"column": name}},
        }
        for name, dtype, text in columns
    ]


def _hdr_objects(ts: TestSet, facts: CampaignFacts) -> list[dict[str, Any]]:
    response = "unknown (the campaign was not given)"
    if facts.response is not None:
        kind = facts.response.get("kind")
        response = (
            f"calibration file sha256:{facts.response.get('sha256')}"
            if kind == "file"
            else "estimated from each bracket by solidkit (no calibration file)"
        )
    out = []
    for s in ts.scenes:
        for cid, cap, rel in hdr_files(s):
            entry = ts.files[rel]
            obj: dict[str, Any] = {
                "@type": "cr:FileObject",
                "@id": f"{DATA}/{rel}",
                "name": f"{DATA}/{rel}",
                "contentUrl": f"{DATA}/{rel}",
                "encodingFormat": "image/x-exr",
                "contentSize": f"{entry.bytes} B",
                "sha256": entry.sha256,
                "solidkit:capture": f"{s.id}/{cid}",
                "solidkit:radianceUnit": HDR_UNITS,
                "solidkit:colourEncoding": "linear Rec. 709 RGB, float (OpenEXR)",
                "solidkit:frame": "the scene photo's panorama frame, equirectangular (docs/conventions.md 2, 3, 8)",
                "solidkit:bracketExposureTimes": list(cap.capture.bracket_exposures_s),
                "solidkit:responseCurve": response,
            }
            if cap.capture.bracket_iso is not None:
                obj["solidkit:referenceIso"] = cap.capture.bracket_iso
            if cap.capture.bracket_f_number is not None:
                obj["solidkit:referenceFNumber"] = cap.capture.bracket_f_number
            stats = facts.hdr_stats.get(f"{s.id}/{cid}")
            if stats and stats.get("saturated_in_all_frames_fraction") is not None:
                obj["solidkit:clippedFraction"] = float(stats["saturated_in_all_frames_fraction"])
                obj["solidkit:clippedFractionScope"] = (
                    "pixels saturated in every frame of the bracket, of the merged panorama at full resolution "
                    "before alignment (campaign HDR product)"
                )
            out.append(obj)
    return out


def open_questions(info: ExportInfo, facts: CampaignFacts) -> list[str]:
    """What the metadata leaves to the team, as questions."""
    q = []
    if info.license is None:
        q.append(f"{TODO}: under which licence is the dataset published (SPDX id or URL)?")
    if not info.creators:
        q.append(f"{TODO}: who created the dataset (people / organisation to credit)?")
    if info.url is None:
        q.append(f"{TODO}: where is the dataset published (URL)?")
    if info.version is None:
        q.append(f"{TODO}: which release version is this (MAJOR.MINOR.PATCH)?")
    if info.cite_as is None:
        q.append(f"{TODO}: how should users cite the dataset (BibTeX)?")
    if info.date_published is None:
        q.append(f"{TODO}: when is it published (ISO 8601 date)?")
    q.append(f"{TODO}: who captured the scenes (the field notes record no operator)?")
    if not facts.campaign_given:
        q.append(f"{TODO}: export with --campaign to state the HDR clipping and the response curve per file")
    return q


def croissant_metadata(
    ts: TestSet, facts: CampaignFacts, info: ExportInfo, checksums: dict[str, str], description: str
) -> dict[str, Any]:
    """The Croissant 1.1 JSON-LD document; ``checksums``: SHA-256 of the non-data files by export path."""
    context = {
        "@language": "en",
        "@vocab": "https://schema.org/",
        "arrayShape": "cr:arrayShape",
        "citeAs": "cr:citeAs",
        "column": "cr:column",
        "conformsTo": "dct:conformsTo",
        "containedIn": "cr:containedIn",
        "cr": "http://mlcommons.org/croissant/",
        "rai": "http://mlcommons.org/croissant/RAI/",
        "data": {"@id": "cr:data", "@type": "@json"},
        "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
        "dct": "http://purl.org/dc/terms/",
        "description": {"@container": "@language"},
        "equivalentProperty": "cr:equivalentProperty",
        "examples": {"@id": "cr:examples", "@type": "@json"},
        "extract": "cr:extract",
        "field": "cr:field",
        "fileProperty": "cr:fileProperty",
        "fileObject": "cr:fileObject",
        "fileSet": "cr:fileSet",
        "format": "cr:format",
        "includes": "cr:includes",
        "isArray": "cr:isArray",
        "isLiveDataset": "cr:isLiveDataset",
        "jsonPath": "cr:jsonPath",
        "key": "cr:key",
        "md5": "cr:md5",
        "name": {"@container": "@language"},
        "parentField": "cr:parentField",
        "path": "cr:path",
        "recordSet": "cr:recordSet",
        "references": "cr:references",
        "regex": "cr:regex",
        "repeated": "cr:repeated",
        "replace": "cr:replace",
        "samplingRate": "cr:samplingRate",
        "sc": "https://schema.org/",
        "separator": "cr:separator",
        "source": "cr:source",
        "subField": "cr:subField",
        "transform": "cr:transform",
        "solidkit": SOLIDKIT_NS,
    }
    files: list[dict[str, Any]] = [
        {
            "@type": "cr:FileObject",
            "@id": rel,
            "name": rel,
            "contentUrl": rel,
            "encodingFormat": "application/json" if rel.endswith(".json") else "text/csv",
            "sha256": sha,
        }
        for rel, sha in sorted(checksums.items())
    ]
    for fid, pattern, what in (
        ("photo-files", "scenes/*/photo.png", "320x240 sRGB photos (model input)"),
        ("ldr-probes", "scenes/*/probes/*/ldr.png", "256x128 sRGB LDR probes, photo panorama frame"),
        ("saturation-masks", "scenes/*/probes/*/saturation.png", "256x128 masks, 255 where the LDR probe clips"),
    ):
        files.append(
            {
                "@type": "cr:FileSet",
                "@id": fid,
                "name": fid,
                "description": what,
                "encodingFormat": "image/png",
                "includes": f"{DATA}/{pattern}",
            }
        )
    files += _hdr_objects(ts, facts)
    record_sets = [
        {
            "@type": "cr:RecordSet",
            "@id": "scenes",
            "name": "scenes",
            "description": "One record per scene: the photo, its capture, intrinsics and pose, and the sun label.",
            "key": {"@id": "scenes/scene_id"},
            "field": _fields("scenes", "records/scenes.csv", SCENE_COLUMNS),
        },
        {
            "@type": "cr:RecordSet",
            "@id": "probes",
            "name": "probes",
            "description": "One record per local light probe: its pixel in the photo, files and label provenance.",
            "field": _fields("probes", "records/probes.csv", PROBE_COLUMNS),
        },
        {
            "@type": "cr:RecordSet",
            "@id": "photos",
            "name": "photos",
            "description": "The 320x240 photos as images.",
            "field": [
                {
                    "@type": "cr:Field",
                    "@id": "photos/path",
                    "name": "path",
                    "dataType": "sc:Text",
                    "source": {"fileSet": {"@id": "photo-files"}, "extract": {"fileProperty": "filepath"}},
                },
                {
                    "@type": "cr:Field",
                    "@id": "photos/image",
                    "name": "image",
                    "dataType": "sc:ImageObject",
                    "source": {"fileSet": {"@id": "photo-files"}, "extract": {"fileProperty": "content"}},
                },
            ],
        },
    ]
    doc: dict[str, Any] = {
        "@context": context,
        "@type": "sc:Dataset",
        "name": f"solidkit test set {ts.inputs.campaign}",
        "description": description,
        "conformsTo": CONFORMS_TO,
        "keywords": ["lighting estimation", "outdoor", "HDR", "light probe", "spatially-varying lighting"],
        "solidkit:datasetVersion": ts.dataset_version,
        "solidkit:openQuestions": open_questions(info, facts),
        "distribution": files,
        "recordSet": record_sets,
    }
    if info.license is not None:
        doc["license"] = info.license
    if info.creators:
        doc["creator"] = [{"@type": "sc:Person", "name": c} for c in info.creators]
    if info.url is not None:
        doc["url"] = info.url
    if info.version is not None:
        doc["version"] = info.version
    if info.cite_as is not None:
        doc["citeAs"] = info.cite_as
    if info.date_published is not None:
        doc["datePublished"] = info.date_published
    return doc
