"""When and where a capture was taken, and pvlib's sun there and then.

Time: EXIF ``DateTimeOriginal`` (camera clock) with ``OffsetTimeOriginal`` (its UTC offset) as
read by :mod:`solidkit.camera.metadata`; a capture without an offset is not placed in time
(``None``): guessing a zone would turn a clock question into a wrong sun. Place: EXIF GPS.
The solar position is :func:`solidkit.synth.solar.solar_position` (pvlib, NREL SPA, apparent
elevation; azimuth clockwise from true north).
"""

from __future__ import annotations

import datetime as dt
import re
from typing import Any

from solidkit.align.schema import Ephemeris, wrap_deg
from solidkit.synth.solar import solar_position

__all__ = ["DRIFT_HOURS", "at_photo_time", "capture_time", "capture_place", "ephemeris_for", "hours_apart"]

#: Captures further apart in time (hours) get no sun drift correction between them: their clocks,
#: not the sun, are the likely cause.
DRIFT_HOURS = 1.0

_OFFSET = re.compile(r"^([+-])(\d{2}):?(\d{2})$")


def capture_time(metadata: dict[str, Any]) -> tuple[dt.datetime | None, str]:
    """Aware capture time from a shot's metadata (manifest ``Shot.metadata``) and what gave it."""
    raw = metadata.get("datetime_original")
    off = metadata.get("utc_offset")
    if not raw:
        return None, "no DateTimeOriginal"
    try:
        when = dt.datetime.fromisoformat(str(raw))
    except ValueError:
        return None, f"unreadable DateTimeOriginal {raw!r}"
    if when.tzinfo is not None:
        return when, "DateTimeOriginal (aware)"
    m = _OFFSET.match(str(off or "").strip())
    if not m:
        return None, "DateTimeOriginal without OffsetTimeOriginal (UTC offset unknown)"
    sign = 1 if m.group(1) == "+" else -1
    tz = dt.timezone(sign * dt.timedelta(hours=int(m.group(2)), minutes=int(m.group(3))))
    return when.replace(tzinfo=tz), "DateTimeOriginal + OffsetTimeOriginal"


def capture_place(metadata: dict[str, Any]) -> tuple[float, float, float | None] | None:
    """``(lat_deg, lon_deg, alt_m)`` from the metadata's GPS, or ``None``."""
    gps = metadata.get("gps") or {}
    lat, lon = gps.get("lat_deg"), gps.get("lon_deg")
    if lat is None or lon is None:
        return None
    return float(lat), float(lon), (None if gps.get("alt_m") is None else float(gps["alt_m"]))


def ephemeris_for(metadata: dict[str, Any], place: tuple[float, float, float | None] | None = None) -> Ephemeris | None:
    """pvlib's sun at a shot's time, at ``place`` (``(lat, lon, alt)``) or else the shot's GPS.

    The captures of a scene are evaluated at one place (the photo's), so that differences
    between their ephemerides are the sun's motion in time only. ``None`` when the time (with
    its UTC offset) or the place is unknown.
    """
    when, source = capture_time(metadata)
    place = place or capture_place(metadata)
    if when is None or place is None:
        return None
    lat, lon, alt = place
    az, el = solar_position(when, lat, lon, alt or 0.0)
    return Ephemeris(
        time_utc=when.astimezone(dt.timezone.utc).isoformat(),
        latitude_deg=lat,
        longitude_deg=lon,
        altitude_m=alt,
        azimuth_deg=az,
        elevation_deg=el,
        time_source=source,
    )


def hours_apart(a: Ephemeris, b: Ephemeris) -> float:
    """Hours between two ephemerides' times (``>= 0``)."""
    return abs((dt.datetime.fromisoformat(a.time_utc) - dt.datetime.fromisoformat(b.time_utc)).total_seconds()) / 3600.0


def at_photo_time(
    azimuth_deg: float,
    elevation_deg: float,
    ephemeris: Ephemeris | None,
    photo_ephemeris: Ephemeris | None,
    *,
    sun_moves: bool = True,
) -> tuple[float, float]:
    """A sun direction seen at a capture's time (its ``ephemeris``), moved to the photo's time: ``(azimuth,
    elevation)`` in degrees, in the same frame, plus the ephemeris' drift between the two times.

    Unchanged when the sun is taken as static (``sun_moves=False``), when either ephemeris is unknown,
    or when the two times are more than :data:`DRIFT_HOURS` apart.
    """
    az, el = azimuth_deg, elevation_deg
    if (
        sun_moves
        and photo_ephemeris is not None
        and ephemeris is not None
        and hours_apart(photo_ephemeris, ephemeris) <= DRIFT_HOURS
    ):
        az += wrap_deg(photo_ephemeris.azimuth_deg - ephemeris.azimuth_deg)
        el += photo_ephemeris.elevation_deg - ephemeris.elevation_deg
    return az, el
