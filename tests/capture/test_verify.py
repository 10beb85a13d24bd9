"""`solidkit verify` and the check at the start of every ingest: damaged and missing originals found,
what can be rebuilt told from what cannot, and an ingest that repairs what its card still holds."""

from __future__ import annotations

import json
import os
import stat
from datetime import timedelta
from pathlib import Path

import cv2
import numpy as np
import pytest

from solidkit.capture.campaign import ingest
from solidkit.capture.manifest import load_manifest
from tests.support.disk_full import T0, campaign_files, make_fault_card


@pytest.fixture(scope="module")
def fault_card(tmp_path_factory):
    root = tmp_path_factory.mktemp("verify")
    card, response = make_fault_card(root / "card")
    ingest(card, root / "clean", response_path=response)
    return card, response, campaign_files(root / "clean")


@pytest.fixture
def camp(fault_card, tmp_path) -> Path:
    card, response, _ = fault_card
    ingest(card, tmp_path / "camp", response_path=response)
    return tmp_path / "camp"


def _corrupt(path: Path, keep_time: bool = False) -> None:
    """Flip one byte in the middle (same size); ``keep_time``: as bit rot would, the time unchanged."""
    st = path.stat()
    path.chmod(stat.S_IRUSR | stat.S_IWUSR)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    path.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
    if keep_time:
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def _originals(camp: Path) -> tuple[Path, Path, Path]:
    """(a bracket member, the sun frame's original, the photo) of the fault card's campaign."""
    m = load_manifest(camp)
    kind = {s.kind: camp / s.original for s in m.shots}
    return kind["bracket_member"], kind["low_exposure"], kind["photo"]


def test_a_clean_campaign_verifies(camp, cli):
    code, out, _ = cli("verify", camp)
    assert code == 0 and "intact" in out and "2 hashed" in out, out  # originals by size and time; notes, profile hashed
    code, out, _ = cli("verify", camp, "--full", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["ok"] and doc["damage"] == []
    assert doc["checked"] == {"originals": 4, "fieldnotes": 1, "profiles": 1, "products": 2}
    assert doc["hashed"] == 4 + 1 + 1 + 2


def test_damaged_and_missing_originals_found(camp, fault_card, cli):
    card = fault_card[0]
    member, sun, photo = _originals(camp)
    _corrupt(member)  # the time changes: the cheap check hashes it
    sun.chmod(stat.S_IRUSR | stat.S_IWUSR)
    sun.unlink()
    photo.chmod(stat.S_IRUSR | stat.S_IWUSR)  # writable, intact
    (camp / "products/s1/p1/hdr-b01.exr").unlink()
    code, out, _ = cli("verify", camp, "--json")
    assert code == 1
    found = {(d["path"], d["problem"].split(" (")[0]): d for d in json.loads(out)["damage"]}
    rel = lambda p: p.relative_to(camp).as_posix()  # noqa: E731
    assert set(found) == {
        (rel(member), "content differs from its sha256"),
        (rel(sun), "missing"),
        (rel(photo), "writable"),
        ("products/s1/p1/hdr-b01.exr", f"its input original {rel(member)} is damaged"),
        ("products/s1/p1/sun.png", f"its input original {rel(sun)} is damaged"),
    }, set(found)
    d = found[(rel(member), "content differs from its sha256")]
    assert not d["rebuildable"] and d["remedy"].startswith("re-ingest from the card (") and str(card) in d["remedy"]
    assert found[(rel(photo), "writable")]["rebuildable"]
    products = [d for d in found.values() if d["what"] == "product"]
    assert products and all(d["rebuildable"] and d["remedy"].startswith("rebuilt by the next ingest") for d in products)
    code, out, _ = cli("verify", camp)
    assert code == 1 and "re-ingest from the card" in out and "rebuilt by the next ingest" in out


def test_bit_rot_needs_full(camp, cli):
    member, _, _ = _originals(camp)
    _corrupt(member, keep_time=True)
    assert cli("verify", camp)[0] == 0  # size and time as recorded: trusted
    code, out, _ = cli("verify", camp, "--full")
    assert code == 1 and "content differs from its sha256" in out


def test_ingest_restores_what_its_card_holds(camp, fault_card, cli):
    """One original corrupted, one deleted; the re-run does not say "nothing to do"
    but copies both again from the card and rebuilds their products: the clean campaign's bytes."""
    card, response, clean = fault_card
    member, sun, photo = _originals(camp)
    _corrupt(member)
    sun.chmod(stat.S_IRUSR | stat.S_IWUSR)
    sun.unlink()
    photo.chmod(stat.S_IRUSR | stat.S_IWUSR)
    code, out, err = cli("ingest", card, "-o", camp)
    text = " ".join(out.split())
    assert code == 0, text + err
    assert "nothing to do" not in text
    assert text.count("copied again from the card") == 2 and "read-only again" in text
    assert campaign_files(camp) == clean
    assert not photo.stat().st_mode & 0o222
    assert cli("verify", camp, "--full")[0] == 0
    assert "nothing to do" in cli("ingest", card, "-o", camp)[1]


def test_ingest_of_another_card_reports_what_it_cannot_restore(camp, tmp_path, cli):
    """A damaged original whose card is not the one being ingested: listed with its card, exit 2; its
    products are not rebuilt from the damaged copy (they stay as they were)."""
    from solidkit.synth.exif import exif_app1, insert_app1

    member, _, _ = _originals(camp)
    hdr = camp / "products/s1/p1/hdr-b01.exr"
    hdr.unlink()  # would be rebuilt ... from the damaged member
    _corrupt(member)
    other = tmp_path / "card2" / "s2" / "photo"
    other.mkdir(parents=True)
    ok, jpg = cv2.imencode(".jpg", np.full((48, 64), 90, np.uint8))
    app1 = exif_app1(make="Canon", model="EOS R", when=T0 + timedelta(days=1), exposure_time=0.01, f_number=4, iso=100)
    (other / "IMG_0009.JPG").write_bytes(insert_app1(jpg.tobytes(), app1))
    code, out, err = cli("ingest", tmp_path / "card2", "-o", camp)
    text = " ".join((out + err).split())
    assert code == 2, text
    assert f"damaged original {member.relative_to(camp).as_posix()}: content differs" in text
    assert "re-ingest them from their card" in text and "1 stored original(s) damaged" in text
    assert not hdr.exists()  # not built from the damaged copy
    m = load_manifest(camp)
    (prod,) = [p for p in m.products if p.kind == "hdr"]
    assert prod.error_transient and "is damaged" in prod.error


def test_a_damaged_profile_is_reported_then_given_again(camp, fault_card, cli):
    """A modified profile copy: verify says to give it again; until then its products are retried each
    run (not failed for good); given again, the campaign is the clean one's bytes."""
    card, response, clean = fault_card
    (profile,) = (camp / "profiles").iterdir()
    profile.write_text(profile.read_text().replace("0.0", "0.5", 1))
    code, out, _ = cli("verify", camp, "--json")
    (d,) = json.loads(out)["damage"]
    assert code == 1 and d["what"] == "profile" and "--response FILE" in d["remedy"] and not d["rebuildable"]
    (camp / "products/s1/p1/hdr-b01.exr").unlink()
    code, out, _ = cli("ingest", card, "-o", camp)
    assert code == 2 and "was modified" in out, out
    assert all(p.error_transient for p in load_manifest(camp).products if p.error)
    code, out, _ = cli("ingest", card, "-o", camp, "--response", response)
    assert code == 0, out
    assert campaign_files(camp) == clean


def test_originals_of_an_older_campaign_are_hashed_once(camp, fault_card, cli):
    """Originals copied before they got their card file's time (an older campaign): verify hashes them
    (intact); the next ingest adopts the card files' times, after which sizes and times suffice."""
    for p in (camp / "originals").rglob("*.jpg"):
        os.utime(p, ns=(1_000_000_000, 1_000_000_000))
    code, out, _ = cli("verify", camp)
    assert code == 0 and "intact" in out and "6 hashed" in out, out  # 4 originals + field notes + profile
    code, out, _ = cli("ingest", fault_card[0], "-o", camp)
    assert code == 0 and "nothing to do" in out, out
    code, out, _ = cli("verify", camp)
    assert code == 0 and "2 hashed" in out, out
