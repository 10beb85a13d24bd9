"""Group shots into exposure brackets from their timestamps, sequence numbers and exposures.

Rules (applied to the shots of one camera, sorted by capture time, then sequence number, then
name):

1. Shots from different cameras (make/model/serial) or with different image sizes never share
   a bracket.
2. A new bracket starts when the gap between the end of the previous shot (its timestamp plus
   its exposure time) and the next timestamp exceeds ``max_gap_s`` (default 10 s: the Theta SC2
   needs ~8 s per bracket shot; EXIF timestamps have 1-s resolution). Without timestamps, a new
   bracket starts when sequence numbers are not consecutive.
3. A new bracket starts when the exposure (effective: time x ISO / f-number², ``ShotInfo.gain``) repeats one
   already in the current bracket (within 2 %): the camera began the next bracket.

Groups of one shot are single shots, not brackets; :func:`group_brackets` returns them too
(callers decide). Sequence numbers come from the metadata or, failing that, from the digits
at the end of the file stem (``R0010123.JPG`` -> 10123, ``IMG_2600.jpg`` -> 2600).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta

__all__ = ["ShotInfo", "group_brackets", "sequence_from_name", "format_exposure", "gain_from"]

_DIGITS = re.compile(r"(\d+)$")


@dataclass(frozen=True)
class ShotInfo:
    """What grouping needs to know about one shot.

    ``key`` identifies the shot (path or sha256); ``time`` is the capture time (naive local or
    aware), ``exposure`` the exposure time in seconds (``None`` if unknown; it also extends the
    shot in time), ``camera`` any string identifying the body, ``size`` (width, height), and
    ``gain`` the relative sensitivity ``(ISO/100) / N²`` (brackets varying ISO or aperture at a
    fixed shutter are brackets too: rule 3 compares ``exposure · gain``).
    """

    key: str
    time: datetime | None = None
    sequence: int | None = None
    exposure: float | None = None
    camera: str = ""
    size: tuple[int | None, int | None] | None = None
    name: str = ""
    gain: float = 1.0

    @property
    def effective(self) -> float | None:
        """``exposure · gain`` (``None`` without an exposure time)."""
        return None if self.exposure is None else self.exposure * self.gain


def sequence_from_name(name: str) -> int | None:
    """Trailing digits of a file stem (``R0010123.JPG`` -> 10123), or ``None``."""
    stem = name.rsplit("/", 1)[-1].rsplit(".", 1)[0]
    m = _DIGITS.search(stem)
    return int(m.group(1)) if m else None


def format_exposure(t: float | None) -> str:
    """Human-readable exposure: ``1/8000 s``, ``0.3 s``, ``8 s``."""
    if t is None:
        return "?"
    if 0 < t < 0.5:
        return f"1/{round(1.0 / t):g} s"
    return f"{t:g} s"


def _sort_key(s: ShotInfo) -> tuple:
    t = s.time.replace(tzinfo=None) if s.time is not None else datetime.max
    return (t, s.sequence if s.sequence is not None else -1, s.name or s.key)


def _same_exposure(a: float, b: float, tol: float = 0.02) -> bool:
    return abs(a - b) <= tol * max(a, b)


def group_brackets(shots: Sequence[ShotInfo], *, max_gap_s: float = 10.0) -> list[list[ShotInfo]]:
    """Split ``shots`` into brackets (lists sorted by capture order); see the module rules.

    The result is deterministic: groups are ordered by their first shot (camera, time,
    sequence, name).
    """
    by_camera: dict[tuple[str, tuple[int | None, int | None] | None], list[ShotInfo]] = {}
    for s in shots:
        by_camera.setdefault((s.camera, s.size), []).append(s)
    groups: list[list[ShotInfo]] = []
    for _, items in sorted(by_camera.items(), key=lambda kv: (kv[0][0], kv[0][1] or (0, 0))):
        items = sorted(items, key=_sort_key)
        current: list[ShotInfo] = []
        for s in items:
            if current and _starts_new(current, s, max_gap_s):
                groups.append(current)
                current = []
            current.append(s)
        if current:
            groups.append(current)
    groups.sort(key=lambda g: (_sort_key(g[0]), g[0].camera))
    return groups


def _starts_new(current: list[ShotInfo], s: ShotInfo, max_gap_s: float) -> bool:
    prev = current[-1]
    if prev.time is not None and s.time is not None:
        a, b = prev.time, s.time
        if (a.tzinfo is None) != (b.tzinfo is None):
            a, b = a.replace(tzinfo=None), b.replace(tzinfo=None)
        end = a + timedelta(seconds=prev.exposure or 0.0)
        if (b - end).total_seconds() > max_gap_s:
            return True
    elif prev.sequence is not None and s.sequence is not None:
        if s.sequence != prev.sequence + 1:
            return True
    elif (prev.time is None) != (s.time is None):
        return True
    if s.effective is not None and any(
        c.effective is not None and _same_exposure(c.effective, s.effective) for c in current
    ):
        return True
    return False


def gain_from(iso: float | None, f_number: float | None) -> float:
    """Relative sensitivity ``(ISO/100) / N²`` (missing values count as ISO 100, f/1)."""
    return (float(iso) / 100.0 if iso else 1.0) / (float(f_number) ** 2 if f_number else 1.0)
