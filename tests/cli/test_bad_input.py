"""Every ``solidkit`` command answers bad input with one clear line: exit code exactly 2, the expected
message, no traceback, no warning, no new or changed files (no partial outputs), inputs untouched.

One module-scoped folder holds tiny bad inputs (missing, empty, truncated, text renamed to an image,
not a panorama, NaN/Inf pixels, bad JSON profiles); each case runs the real entry point in-process
(the ``cli`` fixture: :func:`solidkit.cli.main` with its error handling) with that folder as working
directory, and compares the folder's listing before and after. An unforeseen exception exits 1 and
so fails every case.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from solidkit.envmap.io import write_exr

# Each case: (id, argv with {d} = the bad-input folder, marks). Outputs always go under {d}.
# SLOW: cases that repeat a mechanism another case already covers (or load torch / Mitsuba); `make test-slow`.
SLOW = (pytest.mark.slow,)
GOOD_PANO = "{d}/pano.exr"
CASES: list[tuple[str, list[str], str, tuple]] = [
    # ---- envmap info / sun: the panorama readers
    ("info-missing", ["envmap", "info", "{d}/missing.exr"], "{d}/missing.exr: no such file", ()),
    ("info-empty-exr", ["envmap", "info", "{d}/empty.exr"], "{d}/empty.exr: not a readable EXR file", ()),
    ("info-trunc-exr", ["envmap", "info", "{d}/trunc.exr"], "{d}/trunc.exr: not a readable EXR file", ()),
    ("info-text-exr", ["envmap", "info", "{d}/text.exr"], "{d}/text.exr: not a readable EXR file", ()),
    ("info-empty-jpg", ["envmap", "info", "{d}/empty.jpg"], "{d}/empty.jpg: not a readable image", SLOW),
    ("info-text-jpg", ["envmap", "info", "{d}/text.jpg"], "{d}/text.jpg: not a readable image", ()),
    (
        "info-trunc-jpg",
        ["envmap", "info", "{d}/trunc.jpg"],
        "{d}/trunc.jpg: truncated JPEG (no end-of-image marker)",
        (),
    ),
    (
        "info-not-pano",
        ["envmap", "info", "{d}/photo.jpg"],
        "{d}/photo.jpg: not an equirectangular panorama: 64x48 (width must be 2 x height)",
        (),
    ),
    ("info-nan", ["envmap", "info", "{d}/nan.exr"], "{d}/nan.exr: 1 pixel(s) are NaN or Inf", ()),
    ("info-inf", ["envmap", "info", "{d}/inf.exr"], "{d}/inf.exr: 1 pixel(s) are NaN or Inf", SLOW),
    ("info-directory", ["envmap", "info", "{d}/sub"], "{d}/sub: is a folder, not an image file", ()),
    (
        "info-unknown-suffix",
        ["envmap", "info", "{d}/notes.txt"],
        "{d}/notes.txt: unknown image type '.txt' (expected .exr or an LDR format)",
        SLOW,
    ),
    ("sun-nan", ["envmap", "sun", "{d}/nan.exr"], "{d}/nan.exr: 1 pixel(s) are NaN or Inf", SLOW),
    (
        "sun-not-pano",
        ["envmap", "sun", "{d}/notpano.exr"],
        "{d}/notpano.exr: not an equirectangular panorama: 24x16 (width must be 2 x height)",
        SLOW,
    ),
    (
        "sun-bad-method",
        ["envmap", "sun", GOOD_PANO, "--method", "best"],
        "Invalid value for '--method': Value error, 'best' is not one of 'core', 'paper'.",
        (),
    ),
    # ---- envmap rotate / crop: outputs
    (
        "rotate-trunc-exr",
        ["envmap", "rotate", "{d}/trunc.exr", "-o", "{d}/new/out.exr"],
        "{d}/trunc.exr: not a readable EXR file",
        SLOW,
    ),
    (
        "rotate-out-parent-is-file",
        ["envmap", "rotate", GOOD_PANO, "-o", "{d}/notes.txt/out.exr"],
        "{d}/notes.txt: File exists (a file is where a folder is needed)",
        (),
    ),
    (
        "rotate-out-unknown-suffix",
        ["envmap", "rotate", GOOD_PANO, "-o", "{d}/out.txt"],
        "{d}/out.txt: unknown output type '.txt' (use .exr, or .png/.jpg for a tonemapped LDR)",
        (),
    ),
    (
        "rotate-out-is-input",
        ["envmap", "rotate", GOOD_PANO, "-o", GOOD_PANO, "--yaw", "10"],
        "{d}/pano.exr: is an input of this command; refusing to overwrite it",
        (),
    ),
    (
        "rotate-out-is-dir",
        ["envmap", "rotate", GOOD_PANO, "-o", "{d}/sub"],
        "{d}/sub: unknown output type '' (use .exr, or .png/.jpg for a tonemapped LDR)",
        SLOW,
    ),
    (
        "rotate-yaw-text",
        ["envmap", "rotate", GOOD_PANO, "-o", "{d}/out.exr", "--yaw", "ten"],
        "Invalid value for '--yaw': Input should be a valid number, unable to parse string as a number",
        (),
    ),
    (
        "rotate-yaw-nan",
        ["envmap", "rotate", GOOD_PANO, "-o", "{d}/out.exr", "--yaw", "nan"],
        "--yaw: angles must be finite degrees, got nan",
        (),
    ),
    (
        "crop-out-is-input",
        ["envmap", "crop", GOOD_PANO, "-o", GOOD_PANO, "--hfov-deg", "60", "--size", "8x6"],
        "{d}/pano.exr: is an input of this command; refusing to overwrite it",
        SLOW,
    ),
    (
        "crop-size-12x",
        ["envmap", "crop", GOOD_PANO, "-o", "{d}/c.png", "--hfov-deg", "60", "--size", "12x"],
        "--size '12x': expected WIDTHxHEIGHT in pixels, e.g. 640x480",
        (),
    ),
    (
        "crop-size-zero",
        ["envmap", "crop", GOOD_PANO, "-o", "{d}/c.png", "--hfov-deg", "60", "--size", "0x0"],
        "--size 0x0: sides must be 1..32000 pixels",
        SLOW,
    ),
    (
        "crop-size-huge",
        ["envmap", "crop", GOOD_PANO, "-o", "{d}/c.png", "--hfov-deg", "60", "--size", "99999999x99999999"],
        "--size 99999999x99999999: sides must be 1..32000 pixels",
        SLOW,
    ),
    (
        "crop-fov-180",
        ["envmap", "crop", GOOD_PANO, "-o", "{d}/c.png", "--hfov-deg", "180", "--size", "8x6"],
        "--hfov-deg: 180 degrees is outside (0, 180)",
        (),
    ),
    (
        "crop-fov-negative",
        ["envmap", "crop", GOOD_PANO, "-o", "{d}/c.png", "--hfov-deg", "-5", "--size", "8x6"],
        "--hfov-deg: -5 degrees is outside (0, 180)",
        SLOW,
    ),
    (
        "crop-fov-nan",
        ["envmap", "crop", GOOD_PANO, "-o", "{d}/c.png", "--hfov-deg", "nan", "--size", "8x6"],
        "--hfov-deg: angles must be finite degrees, got nan",
        SLOW,
    ),
    (
        "crop-pitch-inf",
        ["envmap", "crop", GOOD_PANO, "-o", "{d}/c.png", "--hfov-deg", "60", "--size", "8x6", "--pitch", "inf"],
        "--pitch: angles must be finite degrees, got inf",
        (),
    ),
    # ---- capture
    ("capture-info-missing", ["capture", "info", "{d}/missing.jpg"], "{d}/missing.jpg: no such file", SLOW),
    ("capture-info-empty", ["capture", "info", "{d}/empty.jpg"], "{d}/empty.jpg: empty file (0 bytes)", ()),
    (
        "capture-info-text-jpg",
        ["capture", "info", "{d}/text.jpg"],
        "{d}/text.jpg: not a JPEG or DNG/TIFF file (starts with b'hell')",
        (),
    ),
    (
        "capture-info-trunc-jpg",
        ["capture", "info", "{d}/trunc.jpg"],
        "{d}/trunc.jpg: truncated JPEG (no end-of-image marker)",
        (),
    ),
    (
        "merge-missing",
        ["capture", "merge", "{d}/missing.jpg", "{d}/photo.jpg", "-o", "{d}/m.exr"],
        "{d}/missing.jpg: no such file",
        SLOW,
    ),
    (
        "merge-text-jpg",
        ["capture", "merge", "{d}/text.jpg", "{d}/photo.jpg", "-o", "{d}/m.exr", "--times", "1,2"],
        "{d}/text.jpg: not a JPEG or DNG/TIFF file (starts with b'hell')",
        SLOW,
    ),
    (
        "merge-trunc-jpg",
        ["capture", "merge", "{d}/trunc.jpg", "{d}/photo.jpg", "-o", "{d}/m.exr", "--times", "1,2"],
        "{d}/trunc.jpg: cannot decode image",
        (),
    ),
    (
        "merge-no-exif",
        ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr"],
        "{d}/photo.jpg: no exposure time in the metadata; pass --times t1,t2,...",
        SLOW,
    ),
    (
        "merge-times-count",
        ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "1"],
        "--times has 1 value(s) for 2 frame(s)",
        SLOW,
    ),
    (
        "merge-times-text",
        ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "a,b"],
        "--times: 'a' is not an exposure time in seconds (e.g. 1/8, 0.004 or 2)",
        SLOW,
    ),
    (
        "merge-times-negative",
        ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "-1,0"],
        "--times: exposure times must be positive seconds, got '-1'",
        SLOW,
    ),
    (
        "merge-times-nan",
        ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "nan,1"],
        "--times: exposure times must be positive seconds, got 'nan'",
        (),
    ),
    (
        "merge-sizes-differ",
        ["capture", "merge", "{d}/photo.jpg", "{d}/small.jpg", "-o", "{d}/m.exr", "--times", "1,2"],
        "frame small.jpg is 32x24, expected 64x48 like photo.jpg",
        (),
    ),
    (
        "merge-response-missing",
        [
            "capture",
            "merge",
            "{d}/photo.jpg",
            "{d}/photo2.jpg",
            "-o",
            "{d}/m.exr",
            "--times",
            "1,2",
            "--response",
            "{d}/missing.json",
        ],
        "{d}/missing.json: no such response file",
        SLOW,
    ),
    (
        "merge-response-bad-json",
        [
            "capture",
            "merge",
            "{d}/photo.jpg",
            "{d}/photo2.jpg",
            "-o",
            "{d}/m.exr",
            "--times",
            "1,2",
            "--response",
            "{d}/bad.json",
        ],
        "{d}/bad.json: cannot read response curve",
        (),
    ),
    (
        "merge-response-wrong-json",
        [
            "capture",
            "merge",
            "{d}/photo.jpg",
            "{d}/photo2.jpg",
            "-o",
            "{d}/m.exr",
            "--times",
            "1,2",
            "--response",
            "{d}/wrong.json",
        ],
        "{d}/wrong.json: no response curve found (expected a 256x3 list or a 'response' key)",
        SLOW,
    ),
    (
        "merge-wb-bogus",
        ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "1,2", "--wb", "sunny"],
        "--wb: unknown white balance 'sunny' (camera, daylight, none or r,g,b)",
        (),
    ),
    (
        "merge-ghost-mask-is-input",
        [
            "capture",
            "merge",
            "{d}/photo.jpg",
            "{d}/photo2.jpg",
            "-o",
            "{d}/m.exr",
            "--times",
            "1,2",
            "--ghost-mask",
            "{d}/photo2.jpg",
        ],
        "{d}/photo2.jpg: is an input of this command; refusing to overwrite it",
        (),
    ),
    (
        "merge-out-parent-is-file",
        ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/notes.txt/m.exr", "--times", "1,2"],
        "{d}/notes.txt: File exists (a file is where a folder is needed)",
        (),
    ),
    (
        "unwarp-missing",
        ["capture", "unwarp", "{d}/missing.jpg", "-o", "{d}/u.exr"],
        "{d}/missing.jpg: no such file",
        SLOW,
    ),
    (
        "unwarp-empty",
        ["capture", "unwarp", "{d}/empty.jpg", "-o", "{d}/u.exr"],
        "{d}/empty.jpg: empty file (0 bytes)",
        (),
    ),
    (
        "unwarp-text-jpg",
        ["capture", "unwarp", "{d}/text.jpg", "-o", "{d}/u.exr"],
        "{d}/text.jpg: not a JPEG or DNG/TIFF file (starts with b'hell')",
        SLOW,
    ),
    (
        "unwarp-trunc-exr",
        ["capture", "unwarp", "{d}/trunc.exr", "-o", "{d}/u.exr"],
        "{d}/trunc.exr: not a readable EXR file",
        SLOW,
    ),
    (
        "unwarp-nan-exr",
        ["capture", "unwarp", "{d}/nan.exr", "-o", "{d}/u.exr", "--profile", "theta-s"],
        "{d}/nan.exr: 1 pixel(s) are NaN or Inf",
        (),
    ),
    (
        "unwarp-no-model",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/u.exr"],
        "no shipped lens profile for camera None at 128x64; pass --profile (theta-s, theta-s-video, theta-v, theta-z1 "
        "or a unit.json)",
        SLOW,
    ),
    (
        "unwarp-size-12x",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/u.exr", "--profile", "theta-s", "--size", "12x"],
        "--size '12x': expected WIDTHxHEIGHT in pixels, e.g. 640x480",
        (),
    ),
    (
        "unwarp-size-not-2to1",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/u.exr", "--profile", "theta-s", "--size", "100x100"],
        "--size 100x100: an equirectangular panorama needs W = 2 H (>= 4x2), e.g. 2048x1024",
        (),
    ),
    (
        "unwarp-profile-bogus",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/u.exr", "--profile", "theta-x9"],
        "unknown lens profile 'theta-x9'; shipped: theta-s, theta-s-video, theta-v, theta-z1",
        (),
    ),
    (
        "unwarp-profile-bad-json",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/u.exr", "--profile", "{d}/bad.json"],
        "{d}/bad.json: not a JSON profile",
        (),
    ),
    (
        "unwarp-profile-wrong-json",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/u.exr", "--profile", "{d}/wrong.json"],
        "{d}/wrong.json: has no 'kind' field, expected a 'lens' profile",
        SLOW,
    ),
    (
        "unwarp-vignetting-missing",
        [
            "capture",
            "unwarp",
            "{d}/dual.jpg",
            "-o",
            "{d}/u.exr",
            "--profile",
            "theta-s",
            "--vignetting",
            "{d}/missing.json",
        ],
        "{d}/missing.json: no such profile file",
        SLOW,
    ),
    (
        "unwarp-vignetting-bad-json",
        [
            "capture",
            "unwarp",
            "{d}/dual.jpg",
            "-o",
            "{d}/u.exr",
            "--profile",
            "theta-s",
            "--vignetting",
            "{d}/bad.json",
        ],
        "{d}/bad.json: not a JSON profile",
        SLOW,
    ),
    (
        "unwarp-feather-nan",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/u.exr", "--profile", "theta-s", "--feather", "nan"],
        "--feather: angles must be finite degrees, got nan",
        (),
    ),
    (
        "unwarp-out-unknown-suffix",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/u.txt", "--profile", "theta-s"],
        "{d}/u.txt: unknown output type '.txt' (use .exr, or .png/.jpg for sRGB)",
        (),
    ),
    (
        "unwarp-out-parent-is-file",
        ["capture", "unwarp", "{d}/dual.jpg", "-o", "{d}/notes.txt/u.exr", "--profile", "theta-s"],
        "{d}/notes.txt: File exists (a file is where a folder is needed)",
        SLOW,
    ),
    # ---- calibrate
    (
        "response-missing",
        ["calibrate", "response", "{d}/missing.jpg", "{d}/photo.jpg", "-o", "{d}/r.json", "--times", "1,2"],
        "{d}/missing.jpg: no such file",
        (),
    ),
    (
        "response-text-jpg",
        ["calibrate", "response", "{d}/text.jpg", "{d}/photo.jpg", "-o", "{d}/r.json", "--times", "1,2"],
        "{d}/text.jpg: not a readable image",
        SLOW,
    ),
    (
        "response-one-frame",
        ["calibrate", "response", "{d}/photo.jpg", "-o", "{d}/r.json", "--times", "1"],
        "a response curve needs at least 2 bracketed images, got 1",
        (),
    ),
    (
        "response-no-exif",
        ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json"],
        "{d}/photo.jpg: no EXIF ExposureTime; pass the exposure times explicitly",
        SLOW,
    ),
    (
        "response-times-count",
        ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json", "--times", "1"],
        "--times: 1 exposure time(s) for 2 frame(s)",
        SLOW,
    ),
    (
        "response-times-text",
        ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json", "--times", "1,x"],
        "--times: 'x' is not an exposure time in seconds (e.g. 1/8, 0.004 or 2)",
        (),
    ),
    (
        "response-sizes-differ",
        ["calibrate", "response", "{d}/photo.jpg", "{d}/small.jpg", "-o", "{d}/r.json", "--times", "1,2"],
        "bracketed images differ in size: [(24, 32, 3), (48, 64, 3)]",
        SLOW,
    ),
    (
        "response-samples-too-many",
        [
            "calibrate",
            "response",
            "{d}/photo.jpg",
            "{d}/photo2.jpg",
            "-o",
            "{d}/r.json",
            "--times",
            "2,1",  # photo2.jpg is the darker frame
            "--samples",
            "100000",
        ],
        "Debevec samples must be in 1..3072 (the pixels of one image), got 100000",
        (),
    ),
    (
        "response-out-is-input",
        ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/photo2.jpg", "--times", "1,2"],
        "{d}/photo2.jpg: is an input of this command; refusing to overwrite it",
        SLOW,
    ),
    (
        "response-method-bogus",
        [
            "calibrate",
            "response",
            "{d}/photo.jpg",
            "{d}/photo2.jpg",
            "-o",
            "{d}/r.json",
            "--times",
            "1,2",
            "--method",
            "magic",
        ],
        "unknown response method 'magic' (debevec or robertson)",
        SLOW,
    ),
    (
        "response-samples-zero",
        [
            "calibrate",
            "response",
            "{d}/photo.jpg",
            "{d}/photo2.jpg",
            "-o",
            "{d}/r.json",
            "--times",
            "1,2",
            "--samples",
            "0",
        ],
        "Invalid value for '--samples': Input should be greater than or equal to 1",
        (),
    ),
    (
        "colour-out-is-input",
        ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/pano.exr", "--corners", "1,1,30,1,30,15,1,15"],
        "{d}/pano.exr: is an input of this command; refusing to overwrite it",
        SLOW,
    ),
    (
        "colour-missing",
        ["calibrate", "colour", "{d}/missing.exr", "-o", "{d}/c.json"],
        "{d}/missing.exr: no such file",
        SLOW,
    ),
    (
        "colour-text-exr",
        ["calibrate", "colour", "{d}/text.exr", "-o", "{d}/c.json"],
        "{d}/text.exr: not a readable EXR file",
        SLOW,
    ),
    (
        "colour-nan-exr",
        ["calibrate", "colour", "{d}/nan.exr", "-o", "{d}/c.json"],
        "{d}/nan.exr: 1 pixel(s) are NaN or Inf",
        (),
    ),
    (
        "colour-no-checker",
        ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/c.json"],
        "no ColorChecker 24 found by cv2.mcc; give the corner-patch centres with --corners",
        SLOW,
    ),
    (
        "colour-corners-short",
        ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/c.json", "--corners", "1,2,3"],
        "--corners: expected 8 comma-separated numbers, got 3 in '1,2,3'",
        (),
    ),
    (
        "colour-corners-outside",
        ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/c.json", "--corners", "900,900,950,900,950,950,900,950"],
        "chart patches fall outside the image (check the corners)",
        SLOW,
    ),
    (
        "colour-objective-bogus",
        ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/c.json", "--objective", "best"],
        "unknown CCM objective 'best' (delta-e or linear)",
        SLOW,
    ),
    (
        "colour-8bit-no-response",
        ["calibrate", "colour", "{d}/photo.jpg", "-o", "{d}/c.json"],
        "no ColorChecker 24 found by cv2.mcc; give the corner-patch centres with --corners",
        SLOW,
    ),
    (
        "camera-out-is-input",
        ["calibrate", "camera", "{d}/photo.jpg", "-o", "{d}/photo.jpg", "--hfov-deg", "60"],
        "{d}/photo.jpg: is an input of this command; refusing to overwrite it",
        (),
    ),
    (
        "camera-missing",
        ["calibrate", "camera", "{d}/missing.jpg", "-o", "{d}/k.json"],
        "{d}/missing.jpg: no such file",
        SLOW,
    ),
    (
        "camera-text-jpg",
        ["calibrate", "camera", "{d}/text.jpg", "-o", "{d}/k.json"],
        "{d}/text.jpg: not a JPEG or DNG/TIFF file (starts with b'hell')",
        (),
    ),
    (
        "camera-no-exif",
        ["calibrate", "camera", "{d}/photo.jpg", "-o", "{d}/k.json"],
        "cannot derive K from EXIF: missing FocalLength; give --hfov-deg or a checkerboard",
        SLOW,
    ),
    (
        "camera-fov-zero",
        ["calibrate", "camera", "{d}/photo.jpg", "-o", "{d}/k.json", "--hfov-deg", "0"],
        "--hfov-deg: 0 degrees is outside (0, 180)",
        SLOW,
    ),
    (
        "camera-fov-nan",
        ["calibrate", "camera", "{d}/photo.jpg", "-o", "{d}/k.json", "--hfov-deg", "nan"],
        "--hfov-deg: angles must be finite degrees, got nan",
        (),
    ),
    (
        "camera-pattern-12x",
        ["calibrate", "camera", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/k.json", "--pattern", "12x"],
        "--pattern '12x': expected COLSxROWS, e.g. 9x6",
        (),
    ),
    (
        "camera-pattern-no-board",
        ["calibrate", "camera", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/k.json", "--pattern", "6x9"],
        "checkerboard calibration needs >= 3 usable views, got 0; rejected: photo.jpg: no 6x9 board found; photo2.jpg: "
        "no 6x9 board found",
        SLOW,
    ),
    (
        "camera-dictionary-bogus",
        [
            "calibrate",
            "camera",
            "{d}/photo.jpg",
            "{d}/photo2.jpg",
            "-o",
            "{d}/k.json",
            "--charuco",
            "5x7",
            "--dictionary",
            "DICT_BOGUS",
        ],
        "unknown ArUco dictionary 'DICT_BOGUS' (e.g. DICT_4X4_50, DICT_5X5_100)",
        SLOW,
    ),
    (
        "lens-out-is-input",
        ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/photo.jpg", "--pattern", "6x9"],
        "{d}/photo.jpg: is an input of this command; refusing to overwrite it",
        SLOW,
    ),
    (
        "lens-missing",
        ["calibrate", "lens", "{d}/missing.jpg", "-o", "{d}/l.json", "--pattern", "6x9"],
        "{d}/missing.jpg: no such file",
        (),
    ),
    (
        "lens-no-pattern",
        ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json"],
        "give exactly one of --pattern COLSxROWS (checkerboard inner corners) or --charuco COLSxROWS (squares)",
        SLOW,
    ),
    (
        "lens-pattern-12x",
        ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "12x"],
        "--pattern '12x': expected COLSxROWS, e.g. 9x6",
        SLOW,
    ),
    (
        "lens-no-board",
        ["calibrate", "lens", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/l.json", "--pattern", "6x9"],
        "the Kannala-Brandt fit needs >= 3 usable board views, got 0 (rejected: photo.jpg: no 6x9 board found; "
        "photo2.jpg: no 6x9 board found)",
        SLOW,
    ),
    (
        "lens-model-bogus",
        ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "6x9", "--model", "pinhole"],
        "--model: auto, kb or mei, got 'pinhole'",
        SLOW,
    ),
    (
        "lens-crop-short",
        ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "6x9", "--crop", "1,2"],
        "--crop: expected 4 comma-separated numbers, got 2 in '1,2'",
        (),
    ),
    (
        "lens-ypr-text",
        ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "6x9", "--ypr", "a,b,c"],
        "--ypr: expected comma-separated numbers, got 'a,b,c'",
        SLOW,
    ),
    (
        "lens-add-to-missing",
        ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "6x9", "--add-to", "{d}/missing.json"],
        "{d}/missing.json: no such lens profile file",
        SLOW,
    ),
    (
        "vignetting-out-is-input",
        ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/dual.jpg", "--lens-profile", "theta-s"],
        "{d}/dual.jpg: is an input of this command; refusing to overwrite it",
        (),
    ),
    (
        "vignetting-missing",
        ["calibrate", "vignetting", "{d}/missing.exr", "-o", "{d}/v.json", "--lens-profile", "theta-s"],
        "{d}/missing.exr: no such file",
        SLOW,
    ),
    (
        "vignetting-text-exr",
        ["calibrate", "vignetting", "{d}/text.exr", "-o", "{d}/v.json", "--lens-profile", "theta-s"],
        "{d}/text.exr: not a readable EXR file",
        (),
    ),
    (
        "vignetting-profile-bogus",
        ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/v.json", "--lens-profile", "theta-x9"],
        "unknown lens profile 'theta-x9'; shipped: theta-s, theta-s-video, theta-v, theta-z1",
        (),
    ),
    (
        "vignetting-profile-bad-json",
        ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/v.json", "--lens-profile", "{d}/bad.json"],
        "{d}/bad.json: not a JSON profile",
        SLOW,
    ),
    (
        "vignetting-method-bogus",
        [
            "calibrate",
            "vignetting",
            "{d}/dual.jpg",
            "-o",
            "{d}/v.json",
            "--lens-profile",
            "theta-s",
            "--method",
            "magic",
        ],
        "--method: overlap or flat, got 'magic'",
        SLOW,
    ),
    (
        "vignetting-degree-zero",
        ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/v.json", "--lens-profile", "theta-s", "--degree", "0"],
        "Invalid value for '--degree': Input should be greater than or equal to 1",
        SLOW,
    ),
    (
        "vignetting-nan-exr",
        ["calibrate", "vignetting", "{d}/nan.exr", "-o", "{d}/v.json", "--lens-profile", "theta-s"],
        "{d}/nan.exr: 1 pixel(s) are NaN or Inf",
        SLOW,
    ),
    (
        "overlap-out-is-input",
        ["calibrate", "overlap", "{d}/dual.jpg", "--base", "theta-s", "-o", "{d}/dual.jpg"],
        "{d}/dual.jpg: is an input of this command; refusing to overwrite it",
        SLOW,
    ),
    (
        "overlap-missing",
        ["calibrate", "overlap", "{d}/missing.jpg", "--base", "theta-s", "-o", "{d}/o.json"],
        "{d}/missing.jpg: no such file",
        SLOW,
    ),
    (
        "overlap-text-jpg",
        ["calibrate", "overlap", "{d}/text.jpg", "--base", "theta-s", "-o", "{d}/o.json"],
        "{d}/text.jpg: not a readable image",
        (),
    ),
    (
        "overlap-base-bogus",
        ["calibrate", "overlap", "{d}/dual.jpg", "--base", "theta-x9", "-o", "{d}/o.json"],
        "unknown lens profile 'theta-x9'; shipped: theta-s, theta-s-video, theta-v, theta-z1",
        SLOW,
    ),
    (
        "overlap-base-bad-json",
        ["calibrate", "overlap", "{d}/dual.jpg", "--base", "{d}/bad.json", "-o", "{d}/o.json"],
        "{d}/bad.json: not a JSON profile",
        SLOW,
    ),
    (
        "overlap-sizes-differ",
        ["calibrate", "overlap", "{d}/dual.jpg", "{d}/photo.jpg", "--base", "theta-s", "-o", "{d}/o.json"],
        "all images for one refinement must have the same size",
        (),
    ),
    (
        "fisheye-no-circles",
        ["calibrate", "fisheye", "{d}/dual.jpg", "-o", "{d}/f.json"],
        "the left half of the 128x64 frame has no circular image edge (edge found on 0 % of the rays): not a "
        "dual-fisheye frame?",
        (),
    ),
    (
        "fisheye-not-dual-fisheye",
        ["calibrate", "fisheye", "{d}/pano.exr", "-o", "{d}/f.json"],
        "the left half of the 32x16 frame has no circular image edge",
        SLOW,
    ),
    (
        "fisheye-trunc-jpg",
        ["calibrate", "fisheye", "{d}/trunc.jpg", "-o", "{d}/f.json"],
        "{d}/trunc.jpg: truncated JPEG (no end-of-image marker)",
        (),
    ),
    (
        "fisheye-text-jpg",
        ["calibrate", "fisheye", "{d}/text.jpg", "-o", "{d}/f.json"],
        "{d}/text.jpg: not a readable image",
        SLOW,
    ),
    (
        "fisheye-missing",
        ["calibrate", "fisheye", "{d}/missing.jpg", "-o", "{d}/f.json"],
        "{d}/missing.jpg: no such file",
        SLOW,
    ),
    (
        "fisheye-family-bogus",
        ["calibrate", "fisheye", "{d}/dual.jpg", "-o", "{d}/f.json", "--family", "magic"],
        "--family: auto, equidistant, equisolid, theta; got 'magic'",
        (),
    ),
    (
        "fisheye-out-is-input",
        ["calibrate", "fisheye", "{d}/dual.jpg", "-o", "{d}/dual.jpg"],
        "{d}/dual.jpg: is an input of this command; refusing to overwrite it",
        SLOW,
    ),
    # ---- synth (argument checks happen before any rendering)
    (
        "dataset-shard-text",
        ["synth", "dataset", "--n", "2", "--out", "{d}/ds", "--shard", "abc"],
        "--shard must look like i/N (e.g. 0/4), got 'abc'",
        SLOW,
    ),
    (
        "dataset-shard-range",
        ["synth", "dataset", "--n", "2", "--out", "{d}/ds", "--shard", "3/2"],
        "--shard 3/2: need 0 <= i < N",
        (),
    ),
    (
        "dataset-out-is-file",
        ["synth", "dataset", "--n", "1", "--out", "{d}/notes.txt", "--width", "8", "--height", "6"],
        "{d}/notes.txt: exists and is not a folder (--out {d}/notes.txt)",
        SLOW,
    ),
    (
        "dataset-reference-missing",
        ["synth", "dataset", "--n", "1", "--out", "{d}/ds", "--reference", "{d}/missing"],
        "{d}/missing: no LDR reference images found",
        SLOW,
    ),
    (
        "dataset-variant-bogus",
        ["synth", "dataset", "--n", "1", "--out", "{d}/ds", "--variant", "bogus_rgb"],
        "no usable Mitsuba variant: bogus_rgb: not built",
        SLOW,
    ),
    (
        "filter-out-missing",
        ["synth", "filter", "{d}/missing", "--reference", "{d}/sub"],
        "{d}/missing: no samples (not a dataset of 'solidkit synth dataset')",
        SLOW,
    ),
    (
        "filter-not-a-dataset",
        ["synth", "filter", "{d}/sub", "--reference", "{d}/sub"],
        "{d}/sub: no samples (not a dataset of 'solidkit synth dataset')",
        SLOW,
    ),
    (
        "campaign-brackets-text",
        ["synth", "campaign", "--out", "{d}/camp", "--brackets", "fast,slow"],
        "--brackets: 'fast' is not an exposure time in seconds (e.g. 1/8, 0.004 or 2)",
        (),
    ),
    (
        "campaign-brackets-zero",
        ["synth", "campaign", "--out", "{d}/camp", "--brackets", "1/0"],
        "--brackets: '1/0' is not an exposure time in seconds (e.g. 1/8, 0.004 or 2)",
        SLOW,
    ),
    (
        "campaign-variant-bogus",
        ["synth", "campaign", "--out", "{d}/camp", "--variant", "bogus_rgb", "--scenes", "1", "--probes", "0"],
        "no usable Mitsuba variant: bogus_rgb: not built",
        SLOW,
    ),
    (
        "campaign-truth-not-a-campaign",
        ["synth", "campaign-truth", "{d}/sub"],
        "{d}/sub: not a complete virtual campaign (needs truth/campaign.json and truth/truth.json from 'solidkit synth "
        "campaign')",
        (),
    ),
    ("campaign-truth-missing", ["synth", "campaign-truth", "{d}/missing"], "{d}/missing: no such folder", SLOW),
    (
        "campaign-out-is-file",
        ["synth", "campaign", "--out", "{d}/notes.txt", "--scenes", "1", "--probes", "0"],
        "{d}/notes.txt: exists and is not a folder (--out {d}/notes.txt)",
        SLOW,
    ),
    # ---- ingest
    ("ingest-no-out", ["ingest", "{d}/card"], "Missing option '-o' / '--out'.", ()),
    ("testset-build-no-out", ["testset", "build", "{d}/sub"], "Missing option '-o' / '--out'.", SLOW),
    ("ingest-card-missing", ["ingest", "{d}/missing", "-o", "{d}/camp"], "{d}/missing: card directory not found", ()),
    (
        "ingest-card-is-file",
        ["ingest", "{d}/photo.jpg", "-o", "{d}/camp"],
        "{d}/photo.jpg: card directory not found",
        SLOW,
    ),
    (
        "ingest-card-empty",
        ["ingest", "{d}/sub", "-o", "{d}/camp"],
        "{d}/sub: no captures (.jpg/.jpeg/.dng) on this card",
        (),
    ),
    (
        "ingest-campaign-is-file",
        ["ingest", "{d}/card", "-o", "{d}/notes.txt"],
        "{d}/notes.txt: exists and is not a directory",
        (),
    ),
    (
        "ingest-scene-gap-nan",
        ["ingest", "{d}/card", "-o", "{d}/camp", "--scene-gap", "nan"],
        "--scene-gap must be a positive number of seconds, got nan",
        (),
    ),
    (
        "ingest-profile-bogus",
        ["ingest", "{d}/card", "-o", "{d}/camp", "--profile", "theta-x9"],
        "unknown lens profile 'theta-x9'; shipped: theta-s, theta-s-video, theta-v, theta-z1",
        (),
    ),
    (
        "ingest-vignetting-missing",
        ["ingest", "{d}/card", "-o", "{d}/camp", "--vignetting", "{d}/missing.json"],
        "{d}/missing.json: no such profile file",
        (),
    ),
    (
        "ingest-response-bad-json",
        ["ingest", "{d}/card", "-o", "{d}/camp", "--response", "{d}/bad.json"],
        "{d}/bad.json: cannot read response curve",
        SLOW,
    ),
    # ---- predict
    (
        "predict-missing",
        ["predict", "{d}/missing.jpg", "--at", "4,4", "--out", "{d}/p"],
        "{d}/missing.jpg: no such file",
        SLOW,
    ),
    (
        "predict-text-jpg",
        ["predict", "{d}/text.jpg", "--at", "4,4", "--out", "{d}/p"],
        "{d}/text.jpg: not a readable image",
        SLOW,
    ),
    (
        "predict-trunc-jpg",
        ["predict", "{d}/trunc.jpg", "--at", "4,4", "--out", "{d}/p"],
        "{d}/trunc.jpg: truncated JPEG (no end-of-image marker)",
        SLOW,
    ),
    (
        "predict-at-5",
        ["predict", "{d}/photo.jpg", "--at", "5", "--out", "{d}/p"],
        "--at expects X,Y pixel coordinates (e.g. --at 160,200), got '5'",
        (),
    ),
    (
        "predict-at-text",
        ["predict", "{d}/photo.jpg", "--at", "a,b", "--out", "{d}/p"],
        "--at expects X,Y pixel coordinates (e.g. --at 160,200), got 'a,b'",
        SLOW,
    ),
    (
        "predict-at-outside",
        ["predict", "{d}/photo.jpg", "--at", "1000,1000", "--out", "{d}/p"],
        "probe pixel [1000.0, 1000.0] lies outside the 64x48 image",
        SLOW,
    ),
    (
        "predict-at-nan",
        ["predict", "{d}/photo.jpg", "--at", "nan,3", "--out", "{d}/p"],
        "--at 'nan,3': coordinates must be finite",
        SLOW,
    ),
    (
        "predict-intrinsics-short",
        ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--intrinsics", "1,2"],
        "--intrinsics: expected 4 comma-separated numbers, got 2 in '1,2'",
        SLOW,
    ),
    (
        "predict-fov-zero",
        ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--hfov-deg", "0"],
        "--hfov-deg: 0 degrees is outside (1, 179)",
        SLOW,
    ),
    (
        "predict-pitch-nan",
        ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--pitch", "nan"],
        "--pitch: angles must be finite degrees, got nan",
        (),
    ),
    (
        "predict-checkpoint-missing",
        ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--checkpoint", "{d}/missing.pt"],
        "{d}/missing.pt: no such checkpoint",
        SLOW,
    ),
    (
        "predict-checkpoint-text",
        ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--checkpoint", "{d}/notes.txt"],
        "{d}/notes.txt: not a readable torch checkpoint",
        SLOW,
    ),
    (
        "predict-out-is-file",
        ["predict", "{d}/photo.jpg", "--at", "4,4", "-o", "{d}/notes.txt/p"],
        "{d}/notes.txt: exists and is not a folder (--out {d}/notes.txt/p)",
        SLOW,
    ),
    # ---- demo
    (
        "demo-card-missing",
        ["demo", "--out", "{d}/demo", "--card", "{d}/missing"],
        "{d}/missing: card folder not found",
        (),
    ),
    (
        "demo-card-is-file",
        ["demo", "--out", "{d}/demo", "--card", "{d}/notes.txt"],
        "{d}/notes.txt: card folder not found",
        SLOW,
    ),
    (
        "demo-out-is-file",
        ["demo", "--out", "{d}/notes.txt", "--card", "{d}/sub"],
        "{d}/notes.txt: exists and is not a folder",
        (),
    ),
    (
        "demo-model-missing",
        ["demo", "--out", "{d}/demo", "--model", "{d}/missing.pt"],
        "{d}/missing.pt: no such checkpoint",
        (),
    ),
    (
        "demo-truth-not-a-truth",
        ["demo", "--out", "{d}/demo", "--card", "{d}/sub", "--truth", "{d}/sub"],
        "--truth {d}/sub: no truth.json there",
        SLOW,
    ),
    # ---- label
    ("label-serve-missing", ["label", "serve", "{d}/missing"], "{d}/missing: campaign folder not found", ()),
    (
        "label-serve-no-manifest",
        ["label", "serve", "{d}/sub"],
        "{d}/sub: no manifest.json (run `solidkit ingest CARD {d}/sub` first)",
        SLOW,
    ),
    (
        "label-serve-port-0",
        ["label", "serve", "{d}/sub", "--port", "0"],
        "Invalid value for '--port': Input should be greater than or equal to 1",
        SLOW,
    ),
    (
        "label-export-missing",
        ["label", "export", "{d}/missing", "--json"],
        "{d}/missing: campaign folder not found",
        SLOW,
    ),
    (
        "label-export-no-store",
        ["label", "export", "{d}/sub"],
        "{d}/sub: no label store ({d}/sub/labels/labels.sqlite); nothing labelled yet",
        (),
    ),
    # ---- eval / finetune
    ("eval-no-data", ["eval", "-o", "{d}/ev"], "give a real test set (--testset DIR)", ()),
    (
        "eval-testset-missing",
        ["eval", "--testset", "{d}/missing", "-o", "{d}/ev"],
        "--testset {d}/missing: not a folder",
        SLOW,
    ),
    (
        "eval-testset-not-a-testset",
        ["eval", "--testset", "{d}/sub", "-o", "{d}/ev"],
        "--testset {d}/sub: not a test set (no testset.json; run 'solidkit testset build')",
        (),
    ),
    (
        "eval-baseline-no-name",
        ["eval", "--testset", "{d}/sub", "--baseline", "{d}/notes.txt", "-o", "{d}/ev"],
        "--baseline expects NAME=CHECKPOINT (e.g. --baseline col=ablation_col.pt), got '{d}/notes.txt'",
        SLOW,
    ),
    (
        "eval-model-missing",
        ["eval", "--testset", "{d}/sub", "--model", "{d}/missing.pt", "-o", "{d}/ev"],
        "{d}/missing.pt: no such checkpoint",
        SLOW,
    ),
    (
        "eval-panoramas-missing",
        ["eval", "--panoramas", "{d}/missing.exr", "-o", "{d}/ev"],
        "--panoramas {d}/missing.exr: no such file or folder",
        (),
    ),
    (
        "finetune-testset-not-a-testset",
        ["finetune", "--testset", "{d}/sub", "-o", "{d}/ft"],
        "--testset {d}/sub: not a test set (no testset.json; run 'solidkit testset build')",
        (),
    ),
    (
        "finetune-trainable-bad",
        ["finetune", "--testset", "{d}/sub", "--trainable", "head", "-o", "{d}/ft"],
        "--trainable must be one of pnet+sky, pnet, sky, all, got 'head'",
        SLOW,
    ),
    (
        "finetune-folds-1",
        ["finetune", "--testset", "{d}/sub", "--folds", "1", "-o", "{d}/ft"],
        "Invalid value for '--folds': Input should be greater than or equal to 2",
        SLOW,
    ),
    ("train-config-missing", ["train", "{d}/missing.toml"], "{d}/missing.toml: no such training configuration", ()),
    ("train-config-not-toml", ["train", "{d}/notes.txt"], "{d}/notes.txt: not valid TOML", SLOW),
    (
        "sources-bad-shard",
        ["synth", "sources", "--n", "2", "-o", "{d}/src", "--shard", "3/2"],
        "--shard 3/2: need 0 <= i < N",
        SLOW,
    ),
    (
        "sources-no-positions",
        ["synth", "sources", "--n", "2", "-o", "{d}/src", "--positions-per-block", "0"],
        "Invalid value for '--positions-per-block'",
        (),
    ),
    (
        "train-sun-without-sun-net",
        ["train", "{d}/sun.toml"],
        "{d}/sun.toml: [sun] steps need a model with a sun_net and crops = [folders of panoramas]",
        (),
    ),
]


def _jpeg(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def make_bad_inputs(d: Path) -> None:
    """Write the tiny bad (and a few good) inputs the cases refer to."""
    rng = np.random.default_rng(0)
    d.mkdir(parents=True, exist_ok=True)
    (d / "sub").mkdir()
    (d / "notes.txt").write_text("not an image\n")
    (d / "sun.toml").write_text('crops = ["x"]\n[sun]\nsteps = 5\n')  # the small preset has no sun network
    for name in ("empty.jpg", "empty.exr"):
        (d / name).write_bytes(b"")
    for name in ("text.jpg", "text.exr"):
        (d / name).write_text("hello, I am a text file\n")
    (d / "bad.json").write_text('{"lenses": [')
    (d / "wrong.json").write_text(json.dumps({"hello": 1}))
    pano = (rng.random((16, 32, 3)) * 2).astype(np.float32)
    write_exr(d / "pano.exr", pano)
    write_exr(d / "notpano.exr", pano[:, :24])
    nan = pano.copy()
    nan[3, 5] = np.nan
    write_exr(d / "nan.exr", nan)
    inf = pano.copy()
    inf[4, 6, 1] = np.inf
    write_exr(d / "inf.exr", inf, half=False)
    data = (d / "pano.exr").read_bytes()
    (d / "trunc.exr").write_bytes(data[: len(data) // 2])
    photo = (rng.random((48, 64, 3)) * 255).astype(np.uint8)
    (d / "photo.jpg").write_bytes(_jpeg(photo))
    (d / "photo2.jpg").write_bytes(_jpeg(photo // 2))
    (d / "small.jpg").write_bytes(_jpeg(photo[:24, :32]))
    (d / "dual.jpg").write_bytes(_jpeg((rng.random((64, 128, 3)) * 255).astype(np.uint8)))
    jpg = (d / "photo.jpg").read_bytes()
    (d / "trunc.jpg").write_bytes(jpg[: len(jpg) // 3])
    card = d / "card" / "DCIM"
    card.mkdir(parents=True)
    (card / "R0010001.JPG").write_bytes(jpg[: len(jpg) // 3])


def snapshot(d: Path) -> dict[str, tuple[int, int]]:
    """Every path under ``d`` (directories too) with its size and mtime."""
    out = {}
    for p in d.rglob("*"):
        st = p.lstat()
        out[str(p.relative_to(d))] = (st.st_size if p.is_file() else -1, st.st_mtime_ns)
    return out


@pytest.fixture(scope="module")
def bad_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bad") / "in"
    make_bad_inputs(d)
    return d


@pytest.mark.parametrize("argv, message", [pytest.param(a, msg, id=i, marks=m) for i, a, msg, m in CASES])
def test_bad_input_is_one_clear_line(cli, bad_dir: Path, monkeypatch, argv: list[str], message: str) -> None:
    monkeypatch.chdir(bad_dir)
    monkeypatch.setenv("COLUMNS", "200")
    monkeypatch.delenv("SOLIDKIT_DEBUG", raising=False)
    args = [a.replace("{d}", str(bad_dir)) for a in argv]
    before = snapshot(bad_dir)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, out, err = cli(*args)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, (code, err)
    assert lines == [lines[-1]] and lines[-1].startswith("error: "), f"not one error line: {err!r}"
    assert message.replace("{d}", str(bad_dir)) in lines[-1], lines[-1]
    assert "Traceback" not in out + err
    ours = [w for w in caught if issubclass(w.category, (RuntimeWarning, UserWarning))]
    assert not ours, [str(w.message) for w in ours]
    after = snapshot(bad_dir)
    assert after == before, f"files changed: {sorted(set(after.items()) ^ set(before.items()))}"


def test_debug_shows_the_traceback_behind_the_line(cli, bad_dir: Path, monkeypatch) -> None:
    monkeypatch.setenv("SOLIDKIT_DEBUG", "1")
    code, _, err = cli("envmap", "info", bad_dir / "nan.exr")
    assert code == 2
    assert "Traceback (most recent call last)" in err and "PanoramaError" in err
    assert err.strip().splitlines()[-1] == f"error: {bad_dir / 'nan.exr'}: 1 pixel(s) are NaN or Inf"


def test_exit_codes_of_commands_pass_through(cli, bad_dir: Path, monkeypatch) -> None:
    """``raise typer.Exit(3)`` in a command exits 3 (click hands it back instead of raising it)."""
    import typer

    import solidkit.cli.envmap

    def stop(*args, **kwargs):
        raise typer.Exit(3)

    monkeypatch.setattr(solidkit.cli.envmap, "detect_sun", stop)
    assert cli("envmap", "sun", bad_dir / "pano.exr")[0] == 3
    assert cli("envmap", "info", bad_dir / "pano.exr")[0] == 0


def test_unforeseen_errors_exit_1_with_a_hint(cli, bad_dir: Path, monkeypatch) -> None:
    import solidkit.cli.envmap

    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(solidkit.cli.envmap, "detect_sun", broken)
    monkeypatch.delenv("SOLIDKIT_DEBUG", raising=False)
    code, _, err = cli("envmap", "sun", bad_dir / "pano.exr")
    assert code == 1
    assert err.strip().splitlines() == ["error: ZeroDivisionError: a bug (run with SOLIDKIT_DEBUG=1 for the traceback)"]
    monkeypatch.setenv("SOLIDKIT_DEBUG", "1")
    code, _, err = cli("envmap", "sun", bad_dir / "pano.exr")
    assert code == 1 and "Traceback (most recent call last)" in err and "in broken" in err  # the frame that raised
    assert err.strip().splitlines()[-1] == "error: ZeroDivisionError: a bug"


def test_jpeg_truncated(tmp_path: Path) -> None:
    from solidkit.fsutil import jpeg_truncated

    jpg = _jpeg(np.zeros((16, 16, 3), np.uint8))
    cases = {
        "ok.jpg": jpg,
        "padded.jpg": jpg + b"\0" * 100,
        "trailer.jpg": jpg + b"motion-photo video" * 500,  # data after the end marker is legal
        "cut.jpg": jpg[:-10],
        "text.jpg": b"hello",
        "empty.jpg": b"",
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
    assert {n: jpeg_truncated(tmp_path / n) for n in cases} == {
        "ok.jpg": False,
        "padded.jpg": False,
        "trailer.jpg": False,
        "cut.jpg": True,
        "text.jpg": False,
        "empty.jpg": False,
    }


def test_output_naming_an_input_is_refused_except_in_place_updates(tmp_path: Path) -> None:
    from solidkit.cli import refuse_overwriting_inputs
    from solidkit.errors import InputError

    src, other = tmp_path / "a.jpg", tmp_path / "b.json"
    src.write_bytes(b"x")
    other.write_text("{}")
    calls = []
    cmd = refuse_overwriting_inputs(lambda **kw: calls.append(kw))
    with pytest.raises(InputError, match="refusing to overwrite"):
        cmd(frames=[src], out=src)
    with pytest.raises(InputError, match="refusing to overwrite"):
        cmd(image=src, out=tmp_path / "new.json", ghost_mask=src)
    cmd(frames=[src], out=other)  # an existing non-input output is simply replaced
    cmd(views=[src], out=other, add_to=other)  # calibrate lens --add-to P -o P updates P
    assert len(calls) == 2 and src.read_bytes() == b"x"
