"""Parsers of the option values the commands share: sizes, exposure times, angles, numbers and pixels.

Each parser takes the text (or number) as typed and the option's name, and raises
:class:`~solidkit.errors.InputError` (one line, exit code 2) naming the option and showing an
example of what it expects. Every command parses these values here, before any work:

- sizes ``WIDTHxHEIGHT`` (``640x480``; ``x`` or ``X``, spaces allowed): :func:`parse_size`;
- exposure times in seconds, comma-separated, as cameras print them (``1/8,1,8``, ``0.004``):
  :func:`parse_exposure`, :func:`parse_exposures`;
- angles in degrees (finite, optionally within a range): :func:`parse_angle`, :func:`parse_angles`;
- comma-separated numbers (``fx,fy,cx,cy``, ``r,g,b``): :func:`parse_floats`;
- pixels ``X,Y`` (repeatable options) and pixel lists ``X,Y;X,Y``: :func:`parse_pixel`, :func:`parse_pixels`;
- grids ``COLSxROWS`` (board corners): :func:`parse_grid`;
- output folders (``-o DIR``), checked before any work: :func:`output_folder`.
"""

from __future__ import annotations

import math
import re
from fractions import Fraction
from pathlib import Path

from solidkit.errors import InputError

__all__ = [
    "parse_size",
    "parse_grid",
    "parse_exposure",
    "parse_exposures",
    "parse_angle",
    "parse_angles",
    "parse_floats",
    "parse_pixel",
    "parse_pixels",
    "output_folder",
]

MAX_SIDE = 32000  # OpenCV's remap and most image codecs stop below 32767 px

_SIZE = re.compile(r"\s*(\d+)\s*[xX]\s*(\d+)\s*")


def parse_size(
    text: str, option: str = "--size", *, equirect: bool = False, max_side: int = MAX_SIDE
) -> tuple[int, int]:
    """``"640x480"`` -> ``(640, 480)``: positive integers up to ``max_side``; ``equirect``: ``W = 2 H``."""
    m = _SIZE.fullmatch(text or "")
    if not m:
        raise InputError(f"{option} {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 640x480")
    w, h = int(m[1]), int(m[2])
    if min(w, h) < 1 or max(w, h) > max_side:
        raise InputError(f"{option} {text}: sides must be 1..{max_side} pixels")
    if equirect and (w != 2 * h or h < 2):
        raise InputError(f"{option} {text}: an equirectangular panorama needs W = 2 H (>= 4x2), e.g. 2048x1024")
    return w, h


def parse_grid(text: str, option: str = "--pattern", minimum: int = 2) -> tuple[int, int]:
    """``"9x6"`` -> ``(9, 6)`` (board corners or squares, COLSxROWS), each at least ``minimum``."""
    m = _SIZE.fullmatch(text or "")
    if not m:
        raise InputError(f"{option} {text!r}: expected COLSxROWS, e.g. 9x6")
    a, b = int(m[1]), int(m[2])
    if min(a, b) < minimum:
        raise InputError(f"{option} {text}: at least {minimum}x{minimum} needed")
    return a, b


def parse_exposure(text: str, option: str = "--times") -> float:
    """One exposure time in seconds: ``"1/8"``, ``"0.125"``, ``"2"``; finite and positive."""
    t = str(text).strip()
    try:
        value = float(Fraction(t)) if "/" in t else float(t)
    except (ValueError, ZeroDivisionError):
        raise InputError(f"{option}: {t!r} is not an exposure time in seconds (e.g. 1/8, 0.004 or 2)") from None
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"{option}: exposure times must be positive seconds, got {t!r}")
    return value


def parse_exposures(text: str, option: str = "--times", count: int | None = None) -> list[float]:
    """``"1/8,1,8"`` -> ``[0.125, 1.0, 8.0]``; ``count``: how many are required."""
    parts = [p for p in (text or "").split(",") if p.strip()]
    if not parts:
        raise InputError(f"{option}: expected comma-separated exposure times in seconds, e.g. 1/640,1/160,1/40")
    values = [parse_exposure(p, option) for p in parts]
    if count is not None and len(values) != count:
        raise InputError(f"{option}: {len(values)} exposure time(s) for {count} frame(s)")
    return values


def parse_angle(
    value: float, option: str, lo: float | None = None, hi: float | None = None, *, open_interval: bool = False
) -> float:
    """A finite angle in degrees, within ``[lo, hi]`` (``(lo, hi)`` with ``open_interval``) when given."""
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{option}: angles must be finite degrees, got {value}")
    below = lo is not None and (v <= lo if open_interval else v < lo)
    above = hi is not None and (v >= hi if open_interval else v > hi)
    if below or above:
        left = "-inf" if lo is None else f"{lo:g}"
        right = "inf" if hi is None else f"{hi:g}"
        brackets = "()" if open_interval else "[]"
        raise InputError(f"{option}: {v:g} degrees is outside {brackets[0]}{left}, {right}{brackets[1]}")
    return v


def parse_angles(text: str, option: str, count: int | None = None) -> list[float]:
    """``"180,0,0"`` -> ``[180.0, 0.0, 0.0]``: comma-separated finite angles in degrees (e.g. yaw,pitch,roll)."""
    return parse_floats(text, option, count)


def parse_floats(text: str, option: str, count: int | None = None, *, positive: bool = False) -> list[float]:
    """``"1,2.5,3"`` -> ``[1.0, 2.5, 3.0]``: finite numbers (``positive``: > 0), exactly ``count`` when given."""
    try:
        values = [float(x) for x in (text or "").replace(" ", "").split(",") if x]
    except ValueError:
        raise InputError(f"{option}: expected comma-separated numbers, got {text!r}") from None
    if count is not None and len(values) != count:
        raise InputError(f"{option}: expected {count} comma-separated numbers, got {len(values)} in {text!r}")
    if not values or not all(math.isfinite(v) for v in values):
        raise InputError(f"{option}: expected finite numbers, got {text!r}")
    if positive and not all(v > 0 for v in values):
        raise InputError(f"{option}: expected positive numbers, got {text!r}")
    return values


def parse_pixel(text: str, option: str = "--at") -> tuple[float, float]:
    """``"160,200"`` -> ``(160.0, 200.0)``: pixel coordinates X,Y (OpenCV: centres at integers), finite."""
    parts = (text or "").replace(" ", "").split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        raise InputError(f"{option} expects X,Y pixel coordinates (e.g. {option} 160,200), got {text!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise InputError(f"{option} {text!r}: coordinates must be finite")
    return x, y


def parse_pixels(text: str, option: str) -> list[tuple[float, float]]:
    """``"160,200;80,210"`` -> ``[(160, 200), (80, 210)]`` (``;`` or spaces between pixels)."""
    items = [p for p in re.split(r"[;\s]+", text or "") if p]
    if not items:
        raise InputError(f"{option}: expected pixels X,Y separated by ';', e.g. 160,200;80,210")
    return [parse_pixel(p, option) for p in items]


def output_folder(path: Path, option: str = "--out") -> Path:
    """``path`` as a folder to write into: refused when it, or the nearest existing folder above it, is a file."""
    path = Path(path)
    for p in (path, *path.parents):
        if p.exists():
            if not p.is_dir():
                raise InputError(f"{p}: exists and is not a folder ({option} {path})")
            break
    return path
