"""Fuzzed inputs through the ``solidkit`` command: every mutated file must give exit 0 (read as best it can be), a
clear input error (exit 2, one ``error:`` line) or, for ``testset validate``, problem lines (exit 1); never a crash,
a hang or an internal error (exit 1 with the ``SOLIDKIT_DEBUG`` hint).

Seeds (real-ish files from the repository): the shipped mini card (Theta dual-fisheye JPEGs with their EXIF and
XMP, the photo, ``fieldnotes.toml``), the tilt fixtures' street panorama, panoramas and brackets made from them
(EXR, Radiance HDR, PNG, JPEG at small sizes), the real DNG of ``../shared/data/real/raw_dng`` when present
(``$FUZZ_REAL_DNG`` names another), and a test set built from ``tests/support/testset_campaign.py``. Mutations (one
per input, drawn from a seeded ``random.Random``): bit flips, byte overwrites, truncations, a slice deleted or
repeated, and edits of what the format's header says (JPEG/PNG/EXR/TIFF sizes, TIFF entries; TOML/JSON: nesting
1000 to 100 000 deep, NaN, Infinity, 1e400, wrong types, invalid UTF-8).

Commands: ``capture info``, ``capture unwarp``, ``capture merge``, ``envmap sun``, ``predict``, ``ingest`` (a small
card holding the mutated file; ``--no-products`` except every fourth run) and ``testset validate`` (the test set
with one file mutated). Each input runs in a worker process that calls :func:`solidkit.cli.main` in-process (its
error handling included) with file descriptors 1 and 2 sent to files, so what C libraries print is seen; a worker
that dies is a crash (it is restarted), one that does not answer within ``--timeout`` seconds is a hang (killed,
restarted). Library chatter: a line on stderr, outside solidkit's own ``error:``/``warning:`` lines, that a codec
library printed (libjpeg, libpng, OpenEXR, LibRaw, OpenCV's log); ``--json`` output that does not parse is
counted too.

Writes ``benchmarks/results/fuzz_inputs.{md,json}`` (per command: inputs and outcomes; the failing cases with
their mutation, exit code and stderr). Run: ``.venv/bin/python benchmarks/fuzz_inputs.py [--count 1000]
[--seed 0] [--timeout 120] [--only predict,ingest]``; ``--keep DIR`` keeps the failing inputs, ``--cases FILE``
writes every input's outcome (compare two trees with the same ``--seed``), ``--before OLD.json`` adds an older
tree's table to the report.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import random
import re
import select
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

MINI = ROOT / "solidkit" / "assets" / "campaign_mini" / "card"
REAL_DNG = Path(
    os.environ.get("FUZZ_REAL_DNG") or ROOT.parent / "shared" / "data" / "real" / "raw_dng" / "colorchart.dng"
)
OUT = HERE / "results"

#: inputs per command for ``--count 1000`` (scaled to other counts)
WEIGHTS = {
    "capture info": 150,
    "capture unwarp": 150,
    "capture merge": 100,
    "envmap sun": 150,
    "predict": 100,
    "ingest": 150,
    "testset validate": 200,
}

CHATTER = re.compile(
    r"Corrupt JPEG|Premature end of JPEG|Bogus|Invalid JPEG|libpng|EXR_ERR|OpenEXR|Iex|file has 0 parts|"
    r"Exception raised reading|LibRaw|Unexpected end of file|^\[ ?(WARN|ERROR|INFO)|TIFFRead|TIFF directory|"
    r"Not a JPEG|JPEG datastream|Huffman|Wrong JPEG|Unsupported JPEG|Traceback"
)
INTERNAL = "(run with SOLIDKIT_DEBUG=1 for the traceback)"

# ---------------------------------------------------------------- the worker: solidkit.cli.main in-process

WORKER = r"""
import json, os, sys, time, traceback, resource
limit = int(os.environ.get("FUZZ_MEMORY_BYTES", "0"))
if limit:
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
proto = os.fdopen(os.dup(1), "w", buffering=1)
from solidkit.cli import main
proto.write("ready\n")
for line in sys.stdin:
    req = json.loads(line)
    sys.stdout.flush(); sys.stderr.flush()
    out_f, err_f = open(req["stdout"], "wb"), open(req["stderr"], "wb")
    saved = os.dup(1), os.dup(2)
    os.dup2(out_f.fileno(), 1); os.dup2(err_f.fileno(), 2)
    os.chdir(req["cwd"])
    sys.argv = ["solidkit", *req["argv"]]
    t0 = time.perf_counter()
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:
        traceback.print_exc()
        code = "raised"
    seconds = time.perf_counter() - t0
    try:
        sys.stdout.flush(); sys.stderr.flush()
    except Exception:
        pass
    os.dup2(saved[0], 1); os.dup2(saved[1], 2); os.close(saved[0]); os.close(saved[1])
    out_f.close(); err_f.close()
    proto.write(json.dumps({"code": code, "seconds": seconds}) + "\n")
"""


class Worker:
    """A Python process running :data:`WORKER`: one request (argv, cwd) at a time, answered with the exit code."""

    def __init__(self, log: Path, cache: Path):
        env = {**os.environ, "SOLIDKIT_THREADS": "1", "COLUMNS": "100", "PYTHONWARNINGS": "default"}
        env["SOLIDKIT_CACHE_DIR"] = str(cache)  # remap tables of this run only
        env.pop("SOLIDKIT_DEBUG", None)
        self.log = open(log, "ab")
        self.proc = subprocess.Popen(
            [sys.executable, "-c", WORKER],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,
            env=env,
            cwd=ROOT,
            start_new_session=True,
        )
        self.starts = time.perf_counter()
        if self._readline(300) != b"ready\n":
            raise RuntimeError(f"fuzz worker did not start (see {log})")

    def _readline(self, timeout: float) -> bytes | None:
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        return self.proc.stdout.readline() if ready else None

    def call(self, argv: list[str], cwd: Path, stdout: Path, stderr: Path, timeout: float) -> dict:
        assert self.proc.stdin is not None
        req = {"argv": argv, "cwd": str(cwd), "stdout": str(stdout), "stderr": str(stderr)}
        try:
            self.proc.stdin.write((json.dumps(req) + "\n").encode())
            self.proc.stdin.flush()
        except BrokenPipeError:
            return {"outcome": "crash", "detail": f"worker gone (exit {self.proc.poll()})"}
        line = self._readline(timeout)
        if line is None:
            self.kill()
            return {"outcome": "hang", "detail": f"no answer in {timeout:g} s"}
        if not line:
            code = self.proc.wait()
            sig = -code if code < 0 else None
            return {"outcome": "crash", "detail": f"signal {signal.Signals(sig).name}" if sig else f"exit {code}"}
        return json.loads(line)

    def kill(self) -> None:
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait()

    def close(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.kill()
        self.log.close()


# ---------------------------------------------------------------- seeds


def _jpeg(img, quality: int = 90) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return buf.tobytes()


def make_seeds(root: Path) -> dict[str, Path]:
    """The seed files and folders (see the module docstring), under ``root``."""
    import cv2
    import numpy as np

    from solidkit.envmap.io import write_exr, write_ldr
    from solidkit.synth.exif import exif_app1, insert_app1
    from solidkit.testset.build import build_testset
    from tests.support.testset_campaign import make_campaign, world

    root.mkdir(parents=True, exist_ok=True)
    s: dict[str, Path] = {}
    frames = sorted((MINI / "scene01" / "cam").glob("*.JPG"))
    s["theta.jpg"] = frames[0]
    s["photo.jpg"] = MINI / "scene01" / "photo" / "IMG_0001.JPG"
    s["fieldnotes.toml"] = MINI / "scene01" / "fieldnotes.toml"
    import tomllib

    notes = tomllib.loads(s["fieldnotes.toml"].read_text())
    (root / "fieldnotes.json").write_text(json.dumps(notes, indent=1))  # what a tablet app writes
    s["fieldnotes.json"] = root / "fieldnotes.json"
    s["lens.json"] = ROOT / "solidkit" / "camera" / "profiles" / "theta-v.json"
    small = [cv2.resize(cv2.imread(str(f)), (480, 240), interpolation=cv2.INTER_AREA) for f in frames]
    for k, img in enumerate(small):
        (root / f"bracket{k}.jpg").write_bytes(_jpeg(img))
        s[f"bracket{k}.jpg"] = root / f"bracket{k}.jpg"
    s["small_theta.jpg"] = s["bracket1.jpg"]
    cv2.imwrite(str(root / "small_theta.png"), small[1])
    s["small_theta.png"] = root / "small_theta.png"
    lin = ((small[1].astype(np.float32) / 255.0) ** 2.2)[..., ::-1]
    s["small_theta.exr"] = write_exr(root / "small_theta.exr", lin)
    sky = world(40.0, 35.0, height=64)
    s["pano.exr"] = write_exr(root / "pano.exr", sky)
    cv2.imwrite(str(root / "pano.hdr"), np.ascontiguousarray(sky[..., ::-1]))
    s["pano.hdr"] = root / "pano.hdr"
    s["pano.png"] = write_ldr(root / "pano.png", np.clip(sky / max(float(sky.max()), 1e-6), 0, 1) ** (1 / 2.2))
    street = cv2.resize(cv2.imread(str(ROOT / "tests" / "data" / "level_street_3_1024.jpg")), (256, 128))
    (root / "street.jpg").write_bytes(_jpeg(street))
    s["street.jpg"] = root / "street.jpg"
    app1 = exif_app1(  # a stitched Theta capture: capture info measures its stored tilt
        make="RICOH",
        model="RICOH THETA V",
        when=datetime.datetime(2026, 6, 1, 12),
        exposure_time=0.001,
        f_number=2.0,
        iso=64,
        gps=(52.0, 13.0, 40.0),
        theta={"image_type": 1, "roll_deg": 1.5, "pitch_deg": -2.0, "heading_deg": 90.0},
    )
    (root / "theta_pano.jpg").write_bytes(insert_app1(_jpeg(street), app1))
    s["theta_pano.jpg"] = root / "theta_pano.jpg"
    photo = cv2.imread(str(s["photo.jpg"]))
    cv2.imwrite(str(root / "photo.png"), photo)
    s["photo.png"] = root / "photo.png"
    if REAL_DNG.is_file():
        s["real.dng"] = REAL_DNG
    camp = root / "testset_campaign"
    make_campaign(camp)
    build_testset(camp, root / "testset")
    s["testset"] = root / "testset"
    return s


# ---------------------------------------------------------------- mutations


def _flip_bits(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    b = bytearray(data)
    n = rng.randint(1, 8)
    head = rng.random() < 0.5 and len(b) > 0
    for _ in range(n):
        k = rng.randrange(min(len(b), 2048) if head else len(b))
        b[k] ^= 1 << rng.randrange(8)
    return bytes(b), f"{n} bit flip(s){' in the first 2 KiB' if head else ''}"


def _overwrite(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    b = bytearray(data)
    k = rng.randrange(len(b))
    n = rng.randint(1, 16)
    value = rng.choice([0x00, 0xFF, None])
    b[k : k + n] = bytes(rng.randrange(256) if value is None else value for _ in range(len(b[k : k + n])))
    return bytes(b), f"{n} byte(s) overwritten at {k} ({'random' if value is None else hex(value)})"


def _truncate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    n = rng.choice([0, 1, 2, 4, 8, 16, rng.randrange(len(data)), rng.randrange(len(data)), len(data) - 1])
    return data[:n], f"truncated to {n} of {len(data)} bytes"


def _slice(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    a = rng.randrange(len(data))
    n = rng.randint(1, max(1, min(4096, len(data) - a)))
    if rng.random() < 0.5:
        return data[:a] + data[a + n :], f"{n} byte(s) deleted at {a}"
    return data[: a + n] + data[a : a + n] + data[a + n :], f"{n} byte(s) repeated at {a}"


_SIDES = (0, 1, 3, 7, 255, 4095, 65500, 65535)


def _jpeg_header(data: bytes, rng: random.Random) -> tuple[bytes, str] | None:
    b = bytearray(data)
    pos = 2
    while pos + 4 <= len(b) and b[pos] == 0xFF:
        marker, n = b[pos + 1], struct.unpack(">H", b[pos + 2 : pos + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            choice = rng.randrange(4)
            if choice == 0:  # both sides
                h, w = rng.choice(_SIDES), rng.choice(_SIDES)
                b[pos + 5 : pos + 9] = struct.pack(">HH", h, w)
                return bytes(b), f"JPEG frame header says {w}x{h}"
            if choice == 1:  # one side
                k = rng.choice([5, 7])
                v = rng.choice(_SIDES)
                b[pos + k : pos + k + 2] = struct.pack(">H", v)
                return bytes(b), f"JPEG frame header {'height' if k == 5 else 'width'} {v}"
            if choice == 2:  # components / precision
                k = rng.choice([4, 9])
                b[pos + k] = rng.choice([0, 1, 2, 4, 16, 255])
                return bytes(b), f"JPEG frame header byte {k} = {b[pos + k]}"
            b[pos + 2 : pos + 4] = struct.pack(">H", rng.choice([0, 1, 2, 0xFFFF]))
            return bytes(b), "JPEG frame header length edited"
        if marker == 0xE1 and rng.random() < 0.4:  # the EXIF/XMP segment: its length
            b[pos + 2 : pos + 4] = struct.pack(">H", rng.choice([0, 2, 3, n + 1, 0xFFFF]))
            return bytes(b), "APP1 segment length edited"
        pos += 2 + n
    return None


def _png_header(data: bytes, rng: random.Random) -> tuple[bytes, str] | None:
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    b = bytearray(data)
    w, h = rng.choice(_SIDES + (100000, 2**31 - 1)), rng.choice(_SIDES + (100000,))
    b[16:24] = struct.pack(">II", w, h)
    fix = rng.random() < 0.7
    if fix:
        b[29:33] = struct.pack(">I", zlib.crc32(bytes(b[12:29])) & 0xFFFFFFFF)
    if rng.random() < 0.3:
        b[24] = rng.choice([1, 2, 4, 16, 7])  # bit depth
    return bytes(b), f"PNG IHDR says {w}x{h}{' (CRC fixed)' if fix else ''}"


def _exr_header(data: bytes, rng: random.Random) -> tuple[bytes, str] | None:
    if data[:4] != b"\x76\x2f\x31\x01":
        return None
    k = data.find(b"dataWindow\0box2i\0")
    if k < 0:
        return None
    b = bytearray(data)
    v = k + len("dataWindow\0box2i\0") + 4
    which = rng.randrange(4)
    value = rng.choice([-(2**31), -1, 0, 1, 65535, 2**20, 2**31 - 1])
    b[v + 4 * which : v + 4 * which + 4] = struct.pack("<i", value)
    return bytes(b), f"EXR dataWindow[{which}] = {value}"


def _tiff_header(data: bytes, rng: random.Random) -> tuple[bytes, str] | None:
    if data[:4] not in (b"II*\x00", b"MM\x00*"):
        return None
    bo = "<" if data[:2] == b"II" else ">"
    b = bytearray(data)
    ifd = struct.unpack(bo + "I", b[4:8])[0]
    if ifd + 2 > len(b):
        return None
    n = struct.unpack(bo + "H", b[ifd : ifd + 2])[0]
    if n == 0 or ifd + 2 + 12 * n > len(b):
        return None
    e = ifd + 2 + 12 * rng.randrange(n)
    part = rng.choice(["type", "count", "value"])
    if part == "type":
        b[e + 2 : e + 4] = struct.pack(bo + "H", rng.choice([0, 2, 5, 12, 13, 99]))
    elif part == "count":
        b[e + 4 : e + 8] = struct.pack(bo + "I", rng.choice([0, 1, 2**16, 2**31, 2**32 - 1]))
    else:
        b[e + 8 : e + 12] = struct.pack(bo + "I", rng.choice([0, 1, 65535, len(b), 2**31, 2**32 - 1]))
    tag = struct.unpack(bo + "H", b[e : e + 2])[0]
    return bytes(b), f"TIFF IFD0 tag {tag} {part} edited"


def _text_mutation(data: bytes, rng: random.Random, kind: str) -> tuple[bytes, str]:
    text = data.decode("utf-8", "replace")
    choice = rng.randrange(7)
    if choice == 0:
        depth = rng.choice([1000, 1200, 5000, 100000])
        deep = "[" * depth + "]" * depth
        if kind == "json":
            return (text.rstrip()[:-1] + f', "deep": {deep}}}').encode(), f"nested {depth} deep"
        return (f"deep = {deep}\n" + text).encode(), f"nested {depth} deep"
    if choice == 1:
        special = rng.choice(["NaN", "Infinity", "-Infinity", "1e400"] if kind == "json" else ["nan", "inf", "-inf"])
        numbers = list(re.finditer(r"(?<![\w.])-?\d+\.\d+(?![\w.])", text))
        if not numbers:
            return text.encode() + b"\n", "no number to replace"
        m = rng.choice(numbers)
        return (text[: m.start()] + special + text[m.end() :]).encode(), f"a number -> {special}"
    if choice == 2:
        values = list(re.finditer(r'(?<=: )"[^"]*"|(?<== )"[^"]*"', text))
        if not values:
            return text.encode(), "no string to replace"
        m = rng.choice(values)
        other = rng.choice(["[]", "{}", "null" if kind == "json" else "[[1]]", "1", "true", '"' + "x" * 100000 + '"'])
        return (text[: m.start()] + other + text[m.end() :]).encode(), "a string -> another type"
    if choice == 3:
        return data[: rng.randrange(len(data))], "truncated"
    if choice == 4:
        b = bytearray(data)
        b[rng.randrange(len(b))] = rng.choice([0x00, 0xFF, 0xC3, 0x80])
        return bytes(b), "invalid UTF-8 / control byte"
    if choice == 5 and kind == "json":
        m = list(re.finditer(r'"(\w+)": ', text))
        if m:
            k = rng.choice(m)
            return (text[: k.start()] + f'"{k.group(1)}": 0, ' + text[k.start() :]).encode(), "a key repeated"
    return _flip_bits(data, rng)


def mutate(data: bytes, kind: str, rng: random.Random) -> tuple[bytes, str]:
    """One mutation of ``data`` (a file of ``kind``: jpeg, png, exr, hdr, dng, toml or json)."""
    if kind in ("toml", "json"):
        return _text_mutation(data, rng, kind)
    header = {"jpeg": _jpeg_header, "png": _png_header, "exr": _exr_header, "dng": _tiff_header}.get(kind)
    ops: list[Callable] = [_flip_bits, _flip_bits, _overwrite, _truncate, _slice]
    if header is not None:
        ops += [header, header]
    op = rng.choice(ops)
    out = op(data, rng)
    return out if out is not None else _flip_bits(data, rng)


def kind_of(path: Path) -> str:
    return {".jpg": "jpeg", ".png": "png", ".exr": "exr", ".hdr": "hdr", ".dng": "dng", ".toml": "toml"}.get(
        path.suffix.lower(), "json"
    )


# ---------------------------------------------------------------- the cases


@dataclass
class Case:
    command: str
    argv: list[str]
    mutation: str
    target: str
    result: dict = field(default_factory=dict)


def build_case(
    command: str, seeds: dict[str, Path], job: Path, rng: random.Random, index: int, clean: bool = False
) -> Case:
    """Write the mutated input(s) of one run of ``command`` under ``job`` and return its argv (``clean``: the seeds
    as they are, the baseline that must exit 0)."""
    job.mkdir(parents=True)

    def mutated(name: str, dest: Path) -> str:
        data, how = (
            (seeds[name].read_bytes(), "none") if clean else mutate(seeds[name].read_bytes(), kind_of(seeds[name]), rng)
        )
        dest.write_bytes(data)
        return how

    if command == "capture info":
        names = ["theta.jpg", "theta_pano.jpg", "photo.jpg", "street.jpg"]
        name = rng.choice(names + (["real.dng"] * 2 if "real.dng" in seeds else []))
        f = job / f"in{seeds[name].suffix.lower()}"
        return Case(command, ["capture", "info", str(f), "--json"], mutated(name, f), name)
    if command == "capture unwarp":
        name = rng.choice(["theta.jpg", "small_theta.jpg", "small_theta.png", "small_theta.exr", "lens.json"])
        if name == "lens.json":  # the lens profile mutated, the frame as it is
            f, profile = job / "in.jpg", job / "unit.json"
            shutil.copyfile(seeds["small_theta.jpg"], f)
            how = mutated(name, profile)
        else:
            f, profile = job / f"in{seeds[name].suffix.lower()}", None
            how = mutated(name, f)
        argv = ["capture", "unwarp", str(f), "-o", str(job / "out.exr"), "--size", "128x64", "--no-disk-cache"]
        if name != "theta.jpg":  # re-encoded without EXIF: the camera is not known
            argv += ["--profile", str(profile) if profile else "theta-v"]
        return Case(command, argv + ["--json"], how, name)
    if command == "capture merge":
        k = rng.randrange(3)
        files = []
        for j in range(3):
            f = job / f"f{j}.jpg"
            if j == k:
                how = mutated(f"bracket{j}.jpg", f)
            else:
                shutil.copyfile(seeds[f"bracket{j}.jpg"], f)
            files.append(str(f))
        argv = ["capture", "merge", *files, "-o", str(job / "hdr.exr"), "--times", "0.001,0.004,0.016"]
        return Case(command, argv + ["--no-group", "--no-align", "--json"], how, f"bracket{k}.jpg")
    if command == "envmap sun":
        name = rng.choice(["pano.exr", "pano.exr", "pano.hdr", "pano.png", "street.jpg", "theta_pano.jpg"])
        f = job / f"in{seeds[name].suffix.lower()}"
        return Case(command, ["envmap", "sun", str(f), "--json"], mutated(name, f), name)
    if command == "predict":
        name = rng.choice(["photo.jpg", "photo.jpg", "photo.png"])
        f = job / f"in{seeds[name].suffix.lower()}"
        how = mutated(name, f)
        return Case(command, ["predict", str(f), "--at", "100,120", "-o", str(job / "pred"), "--json"], how, name)
    if command == "ingest":
        card = job / "card" / "scene01"
        for sub in ("cam", "photo"):
            (card / sub).mkdir(parents=True)
        picks = ["theta.jpg", "theta.jpg", "photo.jpg", "fieldnotes.toml", "fieldnotes.toml", "fieldnotes.json"]
        name = rng.choice(picks + (["real.dng"] if "real.dng" in seeds else []))
        places = {
            "theta.jpg": card / "cam" / "R0010001.JPG",
            "photo.jpg": card / "photo" / "IMG_0001.JPG",
            "fieldnotes.toml": card / "fieldnotes.toml",
            "fieldnotes.json": card / "fieldnotes.json",
            "real.dng": card / "cam" / "R0010009.DNG",
        }
        how = ""
        notes = "fieldnotes.json" if name == "fieldnotes.json" else "fieldnotes.toml"  # one notes file per scene
        for seed_name, dest in places.items():
            if seed_name == name:
                how = mutated(seed_name, dest)
            elif seed_name not in ("real.dng", "fieldnotes.toml", "fieldnotes.json") or seed_name == notes:
                shutil.copyfile(seeds[seed_name], dest)
        argv = ["ingest", str(job / "card"), "-o", str(job / "campaign")]
        if index % 4:
            argv.append("--no-products")
        return Case(command, argv, how, name)
    if command == "testset validate":
        ts = job / "testset"
        shutil.copytree(seeds["testset"], ts)
        files = sorted(p for p in ts.rglob("*") if p.is_file())
        target = ts / "testset.json" if rng.random() < 0.5 else rng.choice(files)
        data, how = (target.read_bytes(), "none") if clean else mutate(target.read_bytes(), kind_of(target), rng)
        target.write_bytes(data)
        return Case(command, ["testset", "validate", str(ts), "--json"], how, str(target.relative_to(ts)))
    raise ValueError(command)


_SEEDS_OF = {
    "capture info": ["theta.jpg", "theta_pano.jpg", "photo.jpg", "street.jpg", "real.dng"],
    "capture unwarp": ["theta.jpg", "small_theta.jpg", "small_theta.png", "small_theta.exr", "lens.json"],
    "capture merge": ["bracket0.jpg"],
    "envmap sun": ["pano.exr", "pano.hdr", "pano.png", "street.jpg", "theta_pano.jpg"],
    "predict": ["photo.jpg", "photo.png"],
    "ingest": ["theta.jpg", "fieldnotes.json", "real.dng"],
    "testset validate": ["testset.json"],
}


def _seed_names(command: str, seeds: dict[str, Path]) -> list[str]:
    return [n for n in _SEEDS_OF[command] if n in seeds or n == "testset.json"]


class _Pick(random.Random):
    """A ``random.Random`` whose ``choice`` picks ``name`` when it is among the options (the baseline runs)."""

    def __init__(self, name: str):
        super().__init__(0)
        self.name = name

    def choice(self, seq):  # type: ignore[override]
        return self.name if self.name in seq else super().choice(seq)


def judge(case: Case, out: str, err: str) -> str:
    """The outcome of a finished run: ok, input_error, problems (validate), internal, other_exit; plus chatter."""
    code = case.result["code"]
    lines = [line for line in err.splitlines() if line.strip()]
    ours = [line for line in lines if line.startswith(("error: ", "warning: "))]
    chatter = [line for line in lines if line not in ours and CHATTER.search(line)]
    if case.command != "ingest" and code == 2 and len(lines) != 1:  # ingest lists its bad files on their own lines
        chatter += [line for line in lines if line not in ours and line not in chatter]
    if code == 0 and "--json" in case.argv:
        try:
            json.loads(out)
        except ValueError:
            chatter.append("stdout is not one JSON document")
    case.result["chatter"] = chatter[:5]
    if code == "raised" or INTERNAL in err or (code == 1 and case.command != "testset validate"):
        return "internal"
    if code == 0:
        return "ok"
    if code == 2:
        return "input_error"
    if code == 1:  # testset validate: problems found (stdout has them)
        return "problems"
    return "other_exit"


# ---------------------------------------------------------------- the run


def run(count: int, seed: int, timeout: float, only: list[str], keep: Path | None, quiet: bool = False) -> dict:
    commands = [c for c in WEIGHTS if not only or c in only]
    total = sum(WEIGHTS[c] for c in commands)
    counts = {c: max(1, round(count * WEIGHTS[c] / total)) for c in commands}
    rng = random.Random(seed)
    order = [c for c in commands for _ in range(counts[c])]
    rng.shuffle(order)  # interleaved: state leaking from one command into the next would show
    tmp = Path(tempfile.mkdtemp(prefix="solidkit-fuzz-"))
    try:
        seeds = make_seeds(tmp / "seeds")
        cache = tmp / "cache"
        worker = Worker(tmp / "worker.log", cache)
        stats = {c: Counter() for c in commands}
        messages: dict[str, Counter] = {c: Counter() for c in commands}
        cases: list[list] = []  # [index, command, seed file, mutation, exit code, first error/warning line]
        failures: list[dict] = []
        seconds: dict[str, float] = Counter()
        baseline = {}
        for command in commands:  # every seed as it is must pass, else the mutations test nothing
            for name in _seed_names(command, seeds):
                job = tmp / "baseline" / f"{len(baseline):03d}"
                case = build_case(command, seeds, job, _Pick(name), 1, clean=True)
                case.result = worker.call(case.argv, job, job / "o", job / "e", timeout)
                err = (job / "e").read_text(errors="replace") if (job / "e").exists() else ""
                baseline[f"{command} {name}"] = case.result.get("code", case.result.get("outcome"))
                if baseline[f"{command} {name}"] != 0:
                    raise RuntimeError(f"seed {name} fails {command}: {case.result} {err[-2000:]}")
        t0 = time.perf_counter()
        for i, command in enumerate(order):
            job = tmp / "jobs" / f"{i:05d}"
            case = build_case(command, seeds, job, random.Random(rng.getrandbits(64)), i)
            so, se = job / "stdout.txt", job / "stderr.txt"
            t = time.perf_counter()
            case.result = worker.call(case.argv, job, so, se, timeout)
            seconds[command] += time.perf_counter() - t
            out = so.read_text(errors="replace") if so.exists() else ""
            err = se.read_text(errors="replace") if se.exists() else ""
            if "outcome" in case.result:  # crash or hang: a fresh worker for the next input
                outcome = case.result["outcome"]
                worker = Worker(tmp / "worker.log", cache)
            else:
                outcome = judge(case, out, err)
            stats[command][outcome] += 1
            first = next((line for line in err.splitlines() if line.startswith(("error: ", "warning: "))), "")
            cases.append([i, command, case.target, case.mutation, case.result.get("code"), first[:200]])
            if first:
                messages[command][re.sub(r"/\S*/", "", first)[:90]] += 1
            stats[command]["inputs"] += 1
            if case.result.get("chatter"):
                stats[command]["chatter"] += 1
            if outcome == "ok" and any(line.startswith("warning: ") for line in err.splitlines()):
                stats[command]["warned"] += 1
            bad = outcome in ("internal", "crash", "hang", "other_exit") or case.result.get("chatter")
            if bad:
                failures.append(
                    {
                        "index": i,
                        "command": command,
                        "seed_file": case.target,
                        "mutation": case.mutation,
                        "outcome": outcome,
                        "code": case.result.get("code"),
                        "detail": case.result.get("detail"),
                        "chatter": case.result.get("chatter"),
                        "stderr_tail": err.strip().splitlines()[-3:],
                    }
                )
                if keep is not None:
                    shutil.copytree(job, keep / f"{i:05d}", dirs_exist_ok=True)
            if not quiet:
                mark = "!" if bad else "."
                print(mark, end="" if (i + 1) % 80 else f" {i + 1}/{len(order)}\n", flush=True)
            shutil.rmtree(job, ignore_errors=True)
        worker.close()
        wall = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    rows = {}
    for c in commands:
        st = stats[c]
        rows[c] = {
            "inputs": st["inputs"],
            "exit_0": st["ok"],
            "exit_2": st["input_error"],
            "exit_1_problems": st["problems"],
            "exit_1_internal": st["internal"],
            "crashes": st["crash"],
            "hangs": st["hang"],
            "other_exit": st["other_exit"],
            "with_chatter": st["chatter"],
            "exit_0_warned": st["warned"],
            "seconds": round(seconds[c], 1),
            "top_messages": dict(messages[c].most_common(8)),
        }
    return {
        "count": len(order),
        "seed": seed,
        "timeout_s": timeout,
        "wall_s": round(wall, 1),
        "seeds": sorted(seeds),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
        "baseline": baseline,
        "per_command": rows,
        "failures": failures,
        "cases": cases,
    }


def write_report(res: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    doc = {k: v for k, v in res.items() if k != "cases"}  # the per-input list only with --cases
    (out / "fuzz_inputs.json").write_text(json.dumps(doc, indent=1) + "\n")
    cols = [
        "inputs",
        "exit_0",
        "exit_2",
        "exit_1_problems",
        "exit_1_internal",
        "crashes",
        "hangs",
        "other_exit",
        "with_chatter",
        "exit_0_warned",
        "seconds",
    ]
    lines = [
        "# Fuzzed inputs through the CLI",
        "",
        f"`benchmarks/fuzz_inputs.py --count {res['count']} --seed {res['seed']}` ({res['machine']}; "
        f"{res['wall_s']} s wall, {res['timeout_s']:g} s per input before it counts as a hang). One mutation per "
        "input (bit flips, byte overwrites, truncations, a slice deleted or repeated, header edits: JPEG/PNG/EXR "
        "sizes, TIFF entries, TOML/JSON nesting, NaN/Infinity, wrong types, invalid UTF-8) of the seeds: "
        + ", ".join(f"`{s}`" for s in res["seeds"])
        + ". `exit_1_problems`: `testset validate` found problems (its job); `exit_1_internal`: an unforeseen "
        "error; `with_chatter`: a library's own line on stderr or stdout that is not one JSON document; "
        "`exit_0_warned`: exit 0 with a `warning:` line (corrupt JPEG data decoded anyway, naming the file).",
        "",
        "| command | " + " | ".join(cols) + " |",
        "|---|" + "---|" * len(cols),
    ]
    totals = Counter()
    for c, row in res["per_command"].items():
        lines.append(f"| `{c}` | " + " | ".join(str(row[k]) for k in cols) + " |")
        totals.update({k: row[k] for k in cols})
    lines.append("| **all** | " + " | ".join(str(round(totals[k], 1)) for k in cols) + " |")
    before = res.get("before")
    if before:
        lines += [
            "",
            f"The same inputs (seed {before['seed']}) before the fixes ({before['label']}):",
            "",
            "| command | " + " | ".join(cols) + " |",
            "|---|" + "---|" * len(cols),
        ]
        for c, row in before["per_command"].items():
            lines.append(f"| `{c}` | " + " | ".join(str(row.get(k, "")) for k in cols) + " |")
    lines += ["", f"Failing inputs: {len(res['failures'])}."]
    for f in res["failures"][:40]:
        lines.append(
            f"- #{f['index']} `{f['command']}` on `{f['seed_file']}` ({f['mutation']}): {f['outcome']}"
            + (f" ({f['detail']})" if f.get("detail") else "")
            + (f"; chatter {f['chatter']}" if f.get("chatter") else "")
            + (f"; stderr {f['stderr_tail']}" if f["outcome"] != "ok" else "")
        )
    (out / "fuzz_inputs.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=1000, help="inputs in all (split over the commands)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds per input before it is a hang")
    ap.add_argument("--only", default="", help="comma-separated commands, e.g. 'predict,capture info'")
    ap.add_argument("--keep", type=Path, default=None, help="copy each failing input's folder here")
    ap.add_argument("--out", type=Path, default=OUT, help="where fuzz_inputs.{md,json} go")
    ap.add_argument("--before", type=Path, default=None, help="a fuzz_inputs.json of an older tree, shown beside")
    ap.add_argument("--before-label", default="an older tree", help="what --before ran on")
    ap.add_argument("--cases", type=Path, default=None, help="write every input's outcome here (JSON lines)")
    args = ap.parse_args(argv)
    only = [c.strip() for c in args.only.split(",") if c.strip()]
    res = run(args.count, args.seed, args.timeout, only, args.keep)
    if args.before is not None:
        old = json.loads(args.before.read_text())
        rows = {c: {k: v for k, v in row.items() if k != "top_messages"} for c, row in old["per_command"].items()}
        res["before"] = {"label": args.before_label, "seed": old["seed"], "per_command": rows}
    write_report(res, args.out)
    if args.cases is not None:
        args.cases.write_text("".join(json.dumps(c) + "\n" for c in res["cases"]))
    print(
        f"\n{res['count']} inputs in {res['wall_s']} s; {len(res['failures'])} failing; {args.out / 'fuzz_inputs.md'}"
    )
    return 1 if res["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
