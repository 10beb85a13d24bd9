"""The campaign manifest and the virtual campaign's truth on the versioned-document base
(solidkit.document): current files round-trip, older ones (manifest schema 1/2, truth schema 3) are
read, unknown versions and other kinds are one-line errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from solidkit.capture.manifest import (
    FORMAT_VERSION,
    MANIFEST_NAME,
    Manifest,
    ManifestError,
    Scene,
    load_manifest,
    save_manifest,
)
from solidkit.document import VersionedDocument
from solidkit.errors import InputError
from solidkit.synth.campaign_truth import CampaignTruth, TruthError, load_truth

# the shipped mini campaign's truth as schema 3 wrote it (the asset's own truth has since been re-rendered as format 4)
MINI_TRUTH = Path(__file__).resolve().parents[1] / "data" / "campaign_truth_schema3.json"


def _write(folder: Path, data: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / MANIFEST_NAME).write_text(json.dumps(data))
    return folder


def test_manifest_is_a_versioned_document_and_round_trips(tmp_path):
    m = Manifest(
        solidkit_version="0.1.0",
        conventions_version=1,
        cards=["CARD"],
        scenes=[Scene(id="scene01", grouping="folder", start="2024-06-01T12:00:00", end="2024-06-01T12:05:00")],
    )
    assert isinstance(m, VersionedDocument) and (m.kind, m.format_version, m.schema_version) == ("manifest", 3, 3)
    save_manifest(tmp_path, m)
    data = json.loads((tmp_path / MANIFEST_NAME).read_text())
    assert data["kind"] == "manifest" and data["format_version"] == FORMAT_VERSION and "schema_version" not in data
    assert load_manifest(tmp_path) == m


@pytest.mark.parametrize("version", [1, 2])
def test_older_manifests_are_read(tmp_path, version):
    """Files written before the document base (``schema_version`` 1 or 2, no ``kind``) are upgraded in memory;
    a version-1 ``srgb_inverse`` response becomes ``auto`` (the curve estimated from the bracket)."""
    extra = {"response": {"kind": "srgb_inverse"}} if version == 1 else {"fieldnotes": []}
    m = load_manifest(
        _write(
            tmp_path,
            {"schema_version": version, "solidkit_version": "0.0.9", "conventions_version": 1, "cards": ["C"], **extra},
        )
    )
    assert (m.kind, m.format_version, m.cards) == ("manifest", FORMAT_VERSION, ["C"])
    assert m.response == {"kind": "auto"}


@pytest.mark.parametrize(
    "data, message",
    [
        ({"schema_version": 99}, "manifest schema version 99; this solidkit reads format version 3"),
        ({"cards": []}, "manifest schema version None"),
        ({"kind": "manifest", "format_version": 7}, "manifest format version 7; this solidkit reads version 3"),
        ({"kind": "lens", "format_version": 1}, "is a 'lens' manifest, expected 'manifest'"),
        ({"kind": "manifest", "format_version": 3, "cards": "C"}, "invalid manifest manifest: cards"),
        ({"kind": "manifest", "format_version": 3, "shotz": []}, "shotz"),
    ],
)
def test_manifest_errors_are_one_line(tmp_path, data, message):
    with pytest.raises(ManifestError, match=message.replace("(", r"\(").replace(")", r"\)")) as err:
        load_manifest(_write(tmp_path, data))
    assert isinstance(err.value, InputError) and "\n" not in str(err.value)


def test_truth_of_schema_3_is_read_and_rewritten_as_a_document(tmp_path):
    """The shipped mini campaign's first truth (schema 3, ``solidkit-synth-campaign-truth``) reads as format 4."""
    truth = load_truth(MINI_TRUTH)
    assert isinstance(truth, CampaignTruth) and (truth.kind, truth.format_version) == ("campaign-truth", 4)
    out = truth.save(tmp_path / "truth.json")
    again = load_truth(out)
    assert again == truth and json.loads(out.read_text())["kind"] == "campaign-truth"


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.update(schema_version=2), "campaign truth schema version 2"),
        (lambda d: d.update(kind="campaign-truth", format_version=9), "format version 9"),
        (lambda d: d.update(kind="manifest"), "is a 'manifest' truth file, expected 'campaign-truth'"),
        (lambda d: d.pop("scenes"), "scenes"),
    ],
)
def test_truth_errors_are_one_line(tmp_path, edit, message):
    data = json.loads(MINI_TRUTH.read_text())
    edit(data)
    (tmp_path / "truth.json").write_text(json.dumps(data))
    with pytest.raises(TruthError, match=message) as err:
        load_truth(tmp_path / "truth.json")
    assert "\n" not in str(err.value)
    shutil.rmtree(tmp_path)
