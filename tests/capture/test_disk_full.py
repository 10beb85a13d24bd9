"""Fault injection: the disk fills at each write site of ingest, then space is freed (tests/support/disk_full.py).

Each run that meets the full disk exits 2 (never 1), names final files (never a temporary) and the
space missing, remembers nothing as a permanent error; the next run, with space again, ends with a
campaign byte-identical to a clean run's: every file, the manifest included.
"""

from __future__ import annotations

import pytest

from solidkit.capture.campaign import ingest
from solidkit.capture.manifest import MANIFEST_NAME, load_manifest
from tests.support.disk_full import SITES, FullDisk, campaign_files, make_fault_card


@pytest.fixture(scope="module")
def fault_card(tmp_path_factory):
    """The card, its response curve and the files of a clean campaign ingested from them."""
    root = tmp_path_factory.mktemp("faults")
    card, response = make_fault_card(root / "card")
    ingest(card, root / "clean", response_path=response)
    files = campaign_files(root / "clean")
    assert {"products/s1/p1/hdr-b01.exr", "products/s1/p1/sun.png"} <= set(files)
    assert any(k.endswith(".toml") for k in files) and any(k.startswith("profiles/") for k in files)
    return card, response, files


def _differ(a: dict[str, bytes], b: dict[str, bytes]) -> list[str]:
    return sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))


@pytest.mark.parametrize(
    ("site", "after", "sticky"),
    [(s, 0, True) for s in SITES]
    + [("original", 2, True), ("manifest", 1, True)]
    + [(s, 0, False) for s in ("original", "hdr", "sun_frame")],
)
def test_disk_full_at_each_write_site_then_freed(fault_card, tmp_path, cli, site, after, sticky):
    """``sticky``: the disk stays full from that write on; else only that site's files do not fit (the
    manifest saved after them records what failed: it must not be remembered as the data's fault)."""
    card, response, clean = fault_card
    camp = tmp_path / "camp"
    args = ("ingest", card, "-o", camp, "--response", response)
    with FullDisk(site, after, sticky) as disk:
        code, out, err = cli(*args)
    assert disk.failed[site] >= 1, f"the disk never filled at {site}: {dict(disk.seen)}"
    text = " ".join((out + err).split())
    assert code == 2, text
    assert "No space left on device" in text and "0 B free" in text, text
    assert "/." not in text and "Traceback" not in text, text  # final names only, one-line errors
    if (camp / MANIFEST_NAME).exists():
        m = load_manifest(camp)
        assert not m.errors, m.errors  # no card file remembered as bad
        assert all(p.error_transient for p in m.products if p.error), [p.error for p in m.products]
    code, out, err = cli(*args)  # space freed
    assert code == 0, out + err
    assert "nothing to do" not in out
    files = campaign_files(camp)
    assert not _differ(files, clean), _differ(files, clean)
    assert not [k for k in files if k.rsplit("/", 1)[-1].startswith(".") and k != ".lock"]


def test_full_disk_messages_name_the_final_file_and_the_space(fault_card, tmp_path, cli):
    """The HDR EXR (OpenEXR's exception) and the sun frame's PNG (libpng's Write Error): each product
    reported with its final path, the errno's text and the space it needs; once the disk is full the
    products not started yet are not tried; retried by the next run, never remembered."""
    card, response, clean = fault_card
    camp = tmp_path / "camp"
    ingest(card, camp, response_path=response, products=False)
    with FullDisk("hdr") as disk:
        code, out, err = cli("ingest", card, "-o", camp)
    text = " ".join(out.split())
    assert code == 2 and disk.failed == {"hdr": 1, "manifest": 3}, dict(disk.failed)
    assert "products/s1/p1/hdr-b01.exr: could not be built: No space left on device (needs about" in text, text
    assert "s1/p1/sun: not built: the disk is full" in text, text
    assert "manifest.json: No space left on device (needs about" in text + err, text + err
    assert "failed for the environment" in text
    with FullDisk("sun_frame", sticky=False):  # the EXR fits, the PNG does not
        code, out, err = cli("ingest", card, "-o", camp)
    text = " ".join(out.split())
    assert code == 2, text
    assert "products/s1/p1/sun.png: could not be built: No space left on device (needs about" in text, text
    code, out, err = cli("ingest", card, "-o", camp)
    assert code == 0 and "1 / 1 / 0" in " ".join(out.split()), out  # products built / up to date / removed
    assert not _differ(campaign_files(camp), clean)


def test_a_permanent_product_error_is_retried_with_retry_failed(fault_card, tmp_path, cli):
    """A product error recorded before environmental errors were told apart (a campaign of an older
    solidkit: libpng's Write Error as "OpenCV could not write this format") stays until --retry-failed."""
    from solidkit.capture.manifest import save_manifest

    card, response, clean = fault_card
    camp = tmp_path / "camp"
    ingest(card, camp, response_path=response)
    m = load_manifest(camp)
    sun = next(p for p in m.products if p.kind == "sun_frame")
    (camp / sun.path).unlink()
    sun.path = sun.sha256 = None
    sun.error, sun.error_transient = f"{camp}/products/s1/p1/sun.png: OpenCV could not write this format", False
    save_manifest(camp, m)
    code, out, _ = cli("ingest", card, "-o", camp)
    assert code == 2 and "OpenCV could not write this format" in out
    code, out, _ = cli("ingest", card, "-o", camp, "--retry-failed")
    assert code == 0, out
    assert not _differ(campaign_files(camp), clean)


@pytest.fixture
def small_disk(tmp_path):
    """A tmpfs mounted at a temporary folder (root only; skipped elsewhere): ``resize(kib)``."""
    import os
    import subprocess

    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4k", "tmpfs", str(mnt)]).returncode:
        pytest.skip("needs root to mount a small tmpfs")

    def resize(kib: int) -> None:
        subprocess.run(["mount", "-o", f"remount,size={kib}k", str(mnt)], check=True)

    yield mnt, resize
    subprocess.run(["umount", "-l", str(mnt)], check=False)


@pytest.mark.parametrize(("kib", "jobs"), [(8, 1), (24, 1), (48, 1), (96, 1), (148, 1), (96, 2)])  # clean: ~145 kB
def test_a_real_full_disk_then_freed(fault_card, small_disk, cli, kib, jobs):
    """The same on a real file system that fills up (a tmpfs of ``kib`` KiB, then 8 MiB), also with
    worker processes."""
    card, response, clean = fault_card
    mnt, resize = small_disk
    resize(kib)
    camp = mnt / "camp"
    args = ("ingest", card, "-o", camp, "--response", response, "-j", jobs)
    code, out, err = cli(*args)
    text = " ".join((out + err).split())
    assert code == 2, text
    assert "No space left on device" in text and "/." not in text and "Traceback" not in text, text
    resize(8192)
    code, out, err = cli(*args)
    assert code == 0, out + err
    files = campaign_files(camp)
    assert not _differ(files, clean), _differ(files, clean)
