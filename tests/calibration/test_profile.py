"""Profile base: versioned JSON with provenance; loading refuses other kinds, versions, conventions."""

from __future__ import annotations

import json

import pytest

from solidkit.calibration.profile import Profile, ProfileError, load_calibration_profile, make_provenance
from solidkit.calibration.response import ResponseProfile
from solidkit.errors import ConventionsError
from solidkit.fsutil import sha256_file


def _profile(tmp_path):
    src = tmp_path / "input.bin"
    src.write_bytes(b"abc")
    prov = make_provenance([src], tool="test", answer=42)
    return ResponseProfile(
        provenance=prov, method="debevec", curve=[[1.0, 1.0, 1.0]] * 256, residuals={"rms": 0.1}
    ), src


def test_provenance_and_roundtrip(tmp_path):
    prof, src = _profile(tmp_path)
    assert prof.kind == "response" and prof.format_version == 1
    assert prof.provenance.inputs[0].sha256 == sha256_file(src)
    assert prof.provenance.created.endswith("Z") and prof.provenance.parameters == {"answer": 42}
    path = prof.save(tmp_path / "p.json")
    assert not list(tmp_path.glob(".p.json*"))  # atomic write leaves no temporary file
    back = load_calibration_profile(path)
    assert isinstance(back, ResponseProfile) and back == prof


@pytest.mark.parametrize(
    "edit, exc, match",
    [
        (lambda d: d.update(kind="colour"), ProfileError, "expected 'response'"),
        (lambda d: d.update(format_version=2), ProfileError, "format version 2"),
        (lambda d: d["provenance"].update(conventions_version=99), ConventionsError, "conventions version 99"),
        (lambda d: d.update(curve="nope"), ProfileError, "invalid response profile: curve"),
        (lambda d: d.update(extra_field=1), ProfileError, "extra_field"),
    ],
)
def test_bad_profiles_are_refused(tmp_path, edit, exc, match):
    prof, _ = _profile(tmp_path)
    doc = json.loads(prof.model_dump_json())
    edit(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(exc, match=match):
        ResponseProfile.load(path)


def test_load_profile_errors(tmp_path):
    with pytest.raises(ProfileError, match="no such profile"):
        ResponseProfile.load(tmp_path / "missing.json")
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(ProfileError, match="not a JSON profile"):
        load_calibration_profile(tmp_path / "x.json")
    (tmp_path / "y.json").write_text(json.dumps({"kind": "teapot"}))
    with pytest.raises(ProfileError, match="unknown profile kind 'teapot'"):
        load_calibration_profile(tmp_path / "y.json")
    assert Profile.KIND == "profile"
