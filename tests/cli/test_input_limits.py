"""Hostile inputs through the ``solidkit`` entry point, seen at the file-descriptor level (what a terminal shows):
exit 2 with one ``error:`` line whatever library raised, codec chatter inside that line or nowhere, corrupt JPEG
data one ``warning:`` line naming the file; ingest lists such files and goes on with the rest."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.envmap.test_io_limits import bad_chunk_exr, bad_crc_png, corrupt_jpeg, huge_jpeg

MINI = Path(__file__).resolve().parents[2] / "solidkit" / "assets" / "campaign_mini" / "card"


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


@pytest.mark.parametrize(
    "argv", [["capture", "unwarp", "{f}", "-o", "{d}/out.exr"], ["predict", "{f}", "--at", "1,1", "-o", "{d}/pred"]]
)
def test_a_huge_header_is_an_input_error(cli_fd, tmp_path: Path, argv: list[str]) -> None:
    f = tmp_path / "huge.jpg"
    f.write_bytes(huge_jpeg())
    code, _, err = cli_fd(*(a.format(f=f, d=tmp_path) for a in argv))
    assert code == 2, err  # was 1: "error: error: OpenCV(5.0.0) ... validateInputImageSize" on two lines
    assert one_error_line(err) == (
        f"error: {f}: the header states 65500 x 65500 pixels, more than solidkit decodes (178956970 at most)"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["huge.jpg"]


def test_an_unforeseen_library_error_is_one_line_named_by_its_module(cli_fd, tmp_path: Path, monkeypatch) -> None:
    import cv2

    import solidkit.cli.envmap

    def broken(*args, **kwargs):
        raise cv2.error("OpenCV(5.0.0) x.cpp:1: error: (-215:Assertion failed) a in function 'b'\n")

    monkeypatch.setattr(solidkit.cli.envmap, "detect_sun", broken)
    pano = tmp_path / "pano.exr"
    from solidkit.envmap.io import write_exr

    write_exr(pano, __import__("numpy").ones((8, 16, 3), "float32"))
    code, _, err = cli_fd("envmap", "sun", pano)
    assert code == 1
    assert one_error_line(err) == (
        "error: cv2.error: OpenCV(5.0.0) x.cpp:1: error: (-215:Assertion failed) a in function 'b' "
        "(run with SOLIDKIT_DEBUG=1 for the traceback)"
    )  # was "error: error: OpenCV..." with the hint on a second line


def test_corrupt_jpeg_data_is_one_warning_line(cli_fd, tmp_path: Path) -> None:
    f = tmp_path / "corrupt.jpg"
    f.write_bytes(corrupt_jpeg())
    code, out, err = cli_fd("envmap", "info", f, "--json")
    assert code == 0 and json.loads(out)
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"warning: {f}: corrupt image data, decoded with damaged blocks")
    assert "Corrupt JPEG data: " in lines[0]  # libjpeg's words, inside the one line only


def test_libpng_and_openexr_chatter_stays_in_the_line(cli_fd, tmp_path: Path) -> None:
    png = bad_crc_png(tmp_path / "bad.png")
    code, _, err = cli_fd("envmap", "info", png)
    assert code == 2 and one_error_line(err).startswith(f"error: {png}: not a readable image (libpng error: ")
    exr = bad_chunk_exr(tmp_path / "bad.exr")
    code, out, err = cli_fd("envmap", "sun", exr, "--json")
    line = one_error_line(err)
    assert code == 2 and out == "" and "EXR_ERR_BAD_CHUNK_LEADER" in line and "0 parts" not in line


def test_ingest_lists_corrupt_jpegs_and_deep_notes_and_goes_on(cli_fd, tmp_path: Path) -> None:
    card = tmp_path / "card" / "scene01"
    (card / "cam").mkdir(parents=True)
    shutil.copyfile(MINI / "scene01" / "cam" / "R0010001.JPG", card / "cam" / "R0010001.JPG")
    (card / "cam" / "R0010002.JPG").write_bytes(corrupt_jpeg())
    (card / "cam" / "R0010003.JPG").write_bytes(huge_jpeg())
    (card / "fieldnotes.toml").write_text("x = " + "[" * 1200 + "]" * 1200 + "\n")
    camp = tmp_path / "campaign"
    code, out, err = cli_fd("ingest", tmp_path / "card", "-o", camp, "--no-products")
    assert code == 2, err  # the deep notes raised RecursionError: exit 1, no manifest
    manifest = json.loads((camp / "manifest.json").read_text())
    assert [s["sources"][0]["path"] for s in manifest["shots"]] == ["scene01/cam/R0010001.JPG"]
    errors = {e["path"]: e["message"] for e in manifest["errors"]}
    assert errors["scene01/cam/R0010002.JPG"].startswith("cannot decode JPEG: corrupt data (libjpeg: Corrupt JPEG")
    assert "65500 x 65500 pixels" in errors["scene01/cam/R0010003.JPG"]
    assert "Corrupt JPEG data" not in err.replace(errors["scene01/cam/R0010002.JPG"], "")
    listed = [line.strip() for line in out.splitlines() if "R0010002.JPG" in line]
    assert listed == [f"error scene01/cam/R0010002.JPG: {errors['scene01/cam/R0010002.JPG']}"]  # one line, unbroken
    notes = json.dumps(manifest["fieldnotes"])
    assert "fieldnotes.toml: not valid TOML (nested too deep)" in notes


def test_validate_problem_lines_do_not_wrap_into_a_pipe(cli_fd, tmp_path: Path) -> None:
    root = tmp_path / ("a_folder_name_long_enough_that_every_problem_line_is_wider_than_eighty_columns" * 2)
    root.mkdir()
    (root / "testset.json").write_text('{"kind": 1')
    code, _, err = cli_fd("testset", "validate", root)
    assert code == 1
    lines = err.splitlines()
    assert lines[0].startswith("problem [schema] testset.json: ") and lines[0].endswith("(char 10))"), lines
    assert lines[1] == f"{root}: 1 problem(s)"


def test_capture_info_of_a_corrupt_panorama_warns_once(cli_fd, tmp_path: Path) -> None:
    import datetime as dt

    from solidkit.synth.exif import exif_app1, insert_app1

    app1 = exif_app1(
        make="RICOH",
        model="RICOH THETA V",
        when=dt.datetime(2026, 6, 1, 12),
        exposure_time=0.001,
        f_number=2.0,
        iso=64,
        theta={"image_type": 1, "roll_deg": 0.0, "pitch_deg": 0.0},  # stitched: its stored tilt is measured
    )
    f = tmp_path / "R0010001.JPG"
    f.write_bytes(insert_app1(corrupt_jpeg(), app1))
    code, out, err = cli_fd("capture", "info", f, "--json")
    assert code == 0 and json.loads(out)["image_type"] == "equirect"
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"warning: {f}: corrupt image data"), err  # was libjpeg's line


def test_a_training_configuration_nested_too_deep(cli_fd, tmp_path: Path) -> None:
    conf = tmp_path / "deep.toml"
    conf.write_text("steps = " + "[" * 2000 + "]" * 2000 + "\n")
    code, _, err = cli_fd("train", conf)
    assert code == 2 and one_error_line(err) == f"error: {conf}: not valid TOML (nested too deep)"  # was exit 1


def test_merge_warns_about_a_corrupt_frame(cli_fd, tmp_path: Path) -> None:
    import cv2
    import numpy as np

    img = (np.random.default_rng(0).random((64, 128, 3)) * 255).astype(np.uint8)
    frames = []
    for k, gain in enumerate((0.25, 0.5)):
        frames.append(tmp_path / f"f{k}.jpg")
        cv2.imwrite(str(frames[-1]), (img * gain).astype(np.uint8))
    frames.append(tmp_path / "f2.jpg")
    frames[-1].write_bytes(corrupt_jpeg())
    times = "0.001,0.002,0.004"
    args = ["capture", "merge", *frames, "-o", tmp_path / "hdr.exr", "--times", times, "--no-group", "--no-align"]
    code, out, err = cli_fd(*args, "--json")
    assert code == 0 and json.loads(out)
    lines = [line for line in err.splitlines() if line.strip()]
    assert [line.split(": corrupt")[0] for line in lines] == [f"warning: {frames[-1]}"], err  # Pillow said nothing


def test_ingest_says_what_else_was_done(cli_fd, tmp_path: Path) -> None:
    card = tmp_path / "card" / "DCIM"
    card.mkdir(parents=True)
    shutil.copyfile(MINI / "scene01" / "cam" / "R0010001.JPG", card / "R0010001.JPG")
    (card / "R0010002.JPG").write_bytes(huge_jpeg())
    code, _, err = cli_fd("ingest", tmp_path / "card", "-o", tmp_path / "campaign", "--no-products")
    assert code == 2 and one_error_line(err).endswith(
        "1 file(s) on {} could not be ingested (listed above); everything else was ingested".format(tmp_path / "card")
    )  # the sentence stopped at "everything else was"
