"""testset.json schema: the JSON Schema in docs/ is the pydantic model's; content version semantics."""

from __future__ import annotations

import json

import jsonschema
import pytest
from pydantic import ValidationError

from solidkit.testset.schema import TestSet, canonical_json, content_version, json_schema
from tests.conftest import REPO

DOC = REPO / "docs" / "testset.schema.json"


def _minimal() -> dict:
    eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    images = {
        "ldr": "scenes/s/probes/p/ldr.png",
        "ldr_full": "scenes/s/probes/p/ldr_full.png",
        "hdr": None,
        "hdr_full": None,
        "saturation": "scenes/s/probes/p/saturation.png",
        "saturation_full": "scenes/s/probes/p/saturation_full.png",
        "ldr_full_size": [512, 256],
        "saturated_fraction": 0.01,
    }
    probe = {
        "id": "p",
        "pixel": [10.0, 200.0],
        "pixel_full": [20.5, 400.5],
        "pixel_source": "field_notes",
        "ldr": images["ldr"],
        "hdr": None,
        "rotation": eye,
        "alignment": {
            "yaw_deg": 3.0,
            "residual_deg": 0.4,
            "cues": {"sun": {"yaw_deg": 3.1, "weight": 1.0, "ok": True}},
        },
        "images": images,
    }
    scene = {
        "id": "s",
        "photo": "scenes/s/photo.png",
        "photo_full": "scenes/s/photo_full.jpg",
        "photo_size": [320, 240],
        "photo_full_size": [640, 480],
        "crop_box": [0, 0, 640, 480],
        "K": eye,
        "K_full": eye,
        "K_source": "exif-35mm",
        "pitch_deg": -2.0,
        "roll_deg": 0.5,
        "sun": {
            "found": True,
            "azimuth_deg": 20.0,
            "elevation_deg": 40.0,
            "uncertainty_deg": 1.0,
            "source": "annotator",
        },
        "probes": [probe],
        "capture": {"original_sha256": "0" * 64},
    }
    return {
        "version": 1,
        "conventions_version": 1,
        "solidkit_version": "0.1.0",
        "inputs": {"campaign": "c", "manifest_sha256": "1" * 64, "alignment_sha256": "2" * 64},
        "scenes": [scene],
        "files": {"scenes/s/photo.png": {"sha256": "a" * 64, "bytes": 10}},
    }


def test_docs_schema_in_sync():
    """docs/testset.schema.json is exactly what the pydantic model exports (regenerate with
    `solidkit testset schema -o docs/testset.schema.json`)."""
    assert DOC.read_text(encoding="utf-8") == canonical_json(json_schema())


def test_issue_fields_readable_without_solidkit():
    """The issue's minimum fields are in the JSON Schema, so outside tools can rely on them."""
    schema = json.loads(DOC.read_text())
    defs = schema["$defs"]
    assert {"version", "scenes", "files", "dataset_version"} <= set(schema["properties"])
    assert {"id", "photo", "sun", "probes"} <= set(defs["Scene"]["properties"])
    assert {"found", "azimuth_deg", "elevation_deg", "uncertainty_deg", "source"} <= set(defs["Sun"]["properties"])
    assert {"id", "pixel", "pixel_full", "ldr", "hdr", "rotation", "alignment"} <= set(defs["Probe"]["properties"])
    assert {"residual_deg", "cues"} <= set(defs["Alignment"]["properties"])


def test_minimal_document_validates_with_both():
    doc = _minimal()
    TestSet.model_validate(doc)
    jsonschema.validate(json.loads(TestSet.model_validate(doc).model_dump_json()), json.loads(DOC.read_text()))


@pytest.mark.parametrize(
    "path, value",
    [
        (("scenes", 0, "probes", 0, "rotation"), [[1.0, 0.0], [0.0, 1.0]]),
        (("scenes", 0, "sun", "source"), "guess"),
        (("scenes", 0, "probes", 0, "pixel"), [1.0]),
        (("files", "scenes/s/photo.png", "sha256"), "xyz"),
    ],
)
def test_schema_rejects(path, value):
    doc = _minimal()
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(ValidationError):
        TestSet.model_validate(doc)


def test_content_version_tracks_content_only():
    a = TestSet.model_validate(_minimal())
    v = content_version(a)
    assert v.startswith("sha256:") and len(v) == 7 + 16
    assert content_version(a.model_copy(update={"dataset_version": "anything"})) == v
    b = _minimal()
    b["files"]["scenes/s/photo.png"]["sha256"] = "b" * 64
    assert content_version(TestSet.model_validate(b)) != v
