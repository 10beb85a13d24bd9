"""solidkit.cli.parsing (the one parser of sizes, exposures, angles, numbers and pixels) and the CLI's
``--json`` contract: the result alone on stdout, parseable as JSON."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from solidkit.cli.parsing import (
    output_folder,
    parse_angle,
    parse_exposure,
    parse_exposures,
    parse_floats,
    parse_grid,
    parse_pixel,
    parse_pixels,
    parse_size,
)
from solidkit.envmap.io import write_exr
from solidkit.errors import InputError


def test_values_as_typed():
    assert parse_size("640x480") == (640, 480) and parse_size(" 8 X 6 ") == (8, 6)
    assert parse_size("2048x1024", equirect=True) == (2048, 1024)
    assert parse_grid("9x6") == (9, 6)
    assert parse_exposures("1/8,1,8") == [0.125, 1.0, 8.0]
    assert parse_exposures("1/640, 1/160,1/40") == [1 / 640, 1 / 160, 1 / 40]
    assert parse_exposure("0.004") == 0.004 and parse_exposure("1/4000") == 0.00025
    assert parse_angle(-30, "--yaw") == -30.0 and parse_angle(90, "--hfov-deg", 0, 180, open_interval=True) == 90.0
    assert parse_floats("1, 2.5,3", "--x") == [1.0, 2.5, 3.0]
    assert parse_pixel("160,200") == (160.0, 200.0)
    assert parse_pixels("160,200;80.5,210 1,2", "--pixels") == [(160.0, 200.0), (80.5, 210.0), (1.0, 2.0)]


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: parse_size("12x"), "--size '12x': expected WIDTHxHEIGHT in pixels, e.g. 640x480"),
        (lambda: parse_size("0x5"), "--size 0x5: sides must be 1..32000 pixels"),
        (
            lambda: parse_size("100x100", "--out-size", equirect=True),
            "--out-size 100x100: an equirectangular panorama needs W = 2 H",
        ),
        (lambda: parse_grid("1x6"), "--pattern 1x6: at least 2x2 needed"),
        (lambda: parse_exposures("1/8,x"), "--times: 'x' is not an exposure time in seconds (e.g. 1/8, 0.004 or 2)"),
        (lambda: parse_exposures("1/0"), "--times: '1/0' is not an exposure time"),
        (lambda: parse_exposures("-1/8"), "--times: exposure times must be positive seconds, got '-1/8'"),
        (lambda: parse_exposures("inf"), "--times: exposure times must be positive seconds, got 'inf'"),
        (lambda: parse_exposures("1,2", count=3), "--times: 2 exposure time(s) for 3 frame(s)"),
        (lambda: parse_exposures(""), "--times: expected comma-separated exposure times in seconds"),
        (lambda: parse_angle(math.nan, "--yaw"), "--yaw: angles must be finite degrees, got nan"),
        (
            lambda: parse_angle(180, "--hfov-deg", 0, 180, open_interval=True),
            "--hfov-deg: 180 degrees is outside (0, 180)",
        ),
        (lambda: parse_angle(-1, "--feather", 0.0), "--feather: -1 degrees is outside [0, inf]"),
        (lambda: parse_floats("1,2", "--wb", 3), "--wb: expected 3 comma-separated numbers, got 2 in '1,2'"),
        (lambda: parse_floats("1,0,2", "--wb", 3, positive=True), "--wb: expected positive numbers, got '1,0,2'"),
        (lambda: parse_floats("1,nan", "--corners"), "--corners: expected finite numbers, got '1,nan'"),
        (lambda: parse_pixel("5"), "--at expects X,Y pixel coordinates (e.g. --at 160,200), got '5'"),
        (lambda: parse_pixel("inf,3"), "--at 'inf,3': coordinates must be finite"),
        (lambda: parse_pixels(";", "--pixels"), "--pixels: expected pixels X,Y separated by ';'"),
    ],
)
def test_bad_values_name_the_option(call, message):
    with pytest.raises(InputError) as exc:
        call()
    assert message in str(exc.value)


def test_output_folder(tmp_path):
    (tmp_path / "file.txt").write_text("x")
    assert output_folder(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    with pytest.raises(InputError, match=r"file.txt: exists and is not a folder \(-o .*file.txt/sub\)"):
        output_folder(tmp_path / "file.txt" / "sub", "-o")


def test_json_reporters_print_only_json_on_stdout(cli, tmp_path):
    pano = np.zeros((8, 16, 3), np.float32) + 0.5
    pano[1, 4] = 1000.0  # a sun above the horizon
    write_exr(tmp_path / "p.exr", pano)
    code, out, _ = cli("envmap", "info", tmp_path / "p.exr", "--json")
    info = json.loads(out)
    assert code == 0 and (info["width"], info["height"], info["kind"]) == (16, 8, "hdr")
    assert info["luminance_max"] == pytest.approx(1000.0)
    code, out, _ = cli("envmap", "sun", tmp_path / "p.exr", "--json")
    assert code == 0 and json.loads(out)["found"] is True
    code, out, _ = cli("envmap", "rotate", tmp_path / "p.exr", "-o", tmp_path / "r.exr", "--yaw", "90", "--json")
    rot = json.loads(out)
    assert code == 0 and rot["output"] == str(tmp_path / "r.exr") and rot["yaw_deg"] == 90.0 and rot["size"] == [16, 8]
    code, out, _ = cli(
        "envmap", "crop", tmp_path / "p.exr", "-o", tmp_path / "c.exr", "--hfov-deg", "90", "--size", "8x6", "--json"
    )
    crop = json.loads(out)
    assert code == 0 and crop["size"] == [8, 6] and crop["K"][0][0] == pytest.approx(4.0) and crop["K"][0][2] == 3.5
