"""solidkit.flags: a flag's stored string and its parsed code and detail are one thing."""

from __future__ import annotations

import json

import pytest

from solidkit.flags import Flag, FlagCode, disagrees_code, flag_codes, has_code

STORED = [
    "pixel_outside_photo",
    "clock_mismatch: p02 taken more than an hour from the photo (camera clocks or UTC offsets disagree)",
    "features_failed: no match to the camera position; yaw from compass, sun",
    "photo_pose_disagrees: recorded pitch/roll +1.00/-2.00, features +0.10/-0.20 deg",  # a ':' in the detail too
    "annotators_disagree: 2.6 deg (ann)",
]


@pytest.mark.parametrize("text", STORED)
def test_a_stored_flag_reads_back_to_the_same_string(text: str) -> None:
    f = Flag.parse(text)
    assert str(f) == text and Flag.parse(str(f)) == f
    assert f.code == text.split(":", 1)[0] and ":" not in f.code and type(f.code) is str


def test_code_and_detail() -> None:
    f = Flag.parse("photo_pose_disagrees: recorded pitch/roll +1.00/-2.00, features: +0.10 deg")
    assert (f.code, f.detail) == ("photo_pose_disagrees", "recorded pitch/roll +1.00/-2.00, features: +0.10 deg")
    assert Flag.parse("no_pixel") == Flag("no_pixel") and Flag("no_pixel").detail == ""
    assert Flag.parse(f) is f


def test_flag_codes_are_their_stored_strings() -> None:
    f = Flag(FlagCode.NO_SUN_FOUND)
    assert str(f) == "no_sun_found" and type(f.code) is str and f == Flag.parse("no_sun_found")
    assert str(Flag(FlagCode.POSITION_DISAGREES, "p01")) == "position_disagrees: p01"
    assert f"{FlagCode.NO_EPHEMERIS}" == str(FlagCode.NO_EPHEMERIS) == FlagCode.NO_EPHEMERIS.value == "no_ephemeris"
    assert json.dumps([str(Flag(FlagCode.PIXEL_OUTSIDE_PHOTO))]) == '["pixel_outside_photo"]'
    assert len({c.value for c in FlagCode}) == len(FlagCode)
    assert all(c.value == c.value.strip().lower() and ":" not in c.value for c in FlagCode)
    assert disagrees_code("features_via_p01") == "features_via_p01_disagrees"


def test_helpers() -> None:
    flags = ["no_yaw: no cue gave a yaw", Flag(FlagCode.SINGLE_CUE, "yaw from compass only"), "no_yaw"]
    assert flag_codes(flags) == ["no_yaw", "single_cue", "no_yaw"]
    assert has_code(flags, FlagCode.SINGLE_CUE) and has_code(flags, "no_yaw") and not has_code(flags, "no")
    assert not has_code([], FlagCode.NO_YAW)


def test_a_code_holds_no_colon() -> None:
    with pytest.raises(ValueError):
        Flag("a: b")
    with pytest.raises(ValueError):
        Flag(" a")
