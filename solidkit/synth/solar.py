"""Solar geometry for the virtual campaign: a place and a time at which the sun stands where the scene's sun is.

Frames and angles:

- **Solar azimuth** (pvlib, NREL SPA; Reda & Andreas 2004): degrees **clockwise from true
  north** (east = 90°); **elevation**: degrees above the horizon, *apparent* (refracted, pvlib's
  ``apparent_elevation`` with the pressure of the GPS altitude and 12 °C), because a camera sees
  the refracted sun.
- The scene frame of :mod:`solidkit.synth.scene` is x east, y down, z north, so a scene-frame
  direction ``d`` has solar azimuth ``atan2(d_x, d_z)`` and elevation ``asin(-d_y)``.
- A camera's **true heading** is its panorama-frame forward (conventions §2) measured clockwise
  from north: for a camera with yaw ``ψ`` in the scene frame it is ``ψ`` (mod 360°). Our
  panorama azimuth is positive to the right of forward (conventions §3), i.e. clockwise seen
  from above, so ``solar azimuth = heading + panorama azimuth`` and the elevations agree.

:func:`place_sun` inverts the solar position: given a sun direction it draws a day of the
year (its declination), a whole-second UTC time and an altitude, solves the spherical
triangle for latitude and longitude (first guess), and refines both with pvlib by
Gauss-Newton so that pvlib's (azimuth, apparent elevation) at that place and time match the
direction to ~1e-6°. Days whose declination cannot give the requested elevation/azimuth at a
latitude within ``max_abs_lat_deg`` are skipped (a sun 80° high needs the tropics; a low
northern sun at noon needs a southern latitude), so any direction above the horizon has a
solution.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass

import numpy as np

from solidkit.envmap.coords import angles_from_direction, angular_distance, direction_from_angles, wrap_angle
from solidkit.errors import InputError

__all__ = ["SolarFix", "solar_position", "solar_direction", "solar_angles_deg", "place_sun", "utc_offset_text"]

TEMPERATURE_C = 12.0
OBLIQUITY_DEG = 23.44


def solar_angles_deg(d: np.ndarray) -> tuple[float, float]:
    """Scene-frame unit direction ``(3,)`` -> (solar azimuth clockwise from north, elevation), degrees."""
    phi, theta = angles_from_direction(np.asarray(d, np.float64))  # the scene frame is laid out like §2
    return math.degrees(float(phi)) % 360.0, math.degrees(float(theta))


def solar_direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """(azimuth clockwise from north, elevation) in degrees -> unit direction ``(3,)`` in the scene frame."""
    return direction_from_angles(np.radians(float(azimuth_deg)), np.radians(float(elevation_deg)))


def solar_position(when: dt.datetime, lat_deg: float, lon_deg: float, alt_m: float = 0.0) -> tuple[float, float]:
    """pvlib's (azimuth clockwise from north, apparent elevation) in degrees at an aware ``when``."""
    import pandas as pd
    import pvlib

    if when.tzinfo is None:
        raise InputError("solar_position: 'when' must carry a time zone (UTC offset)")
    t = pd.DatetimeIndex([when.astimezone(dt.timezone.utc)])
    sp = pvlib.solarposition.get_solarposition(t, lat_deg, lon_deg, altitude=alt_m, temperature=TEMPERATURE_C)
    return float(sp["azimuth"].iloc[0]), float(sp["apparent_elevation"].iloc[0])


def utc_offset_text(minutes: int) -> str:
    """EXIF ``OffsetTime`` text, e.g. ``+02:00`` / ``-05:30``."""
    sign = "+" if minutes >= 0 else "-"
    return f"{sign}{abs(minutes) // 60:02d}:{abs(minutes) % 60:02d}"


@dataclass(frozen=True)
class SolarFix:
    """A place and time with the sun at a requested direction.

    when_utc: aware UTC datetime (whole seconds); lat/lon: degrees (north, east positive);
    alt_m: metres; utc_offset_min: the local civil offset (nominal zone ``round(lon / 15)`` h);
    azimuth_deg/elevation_deg: pvlib's solar position there and then; error_deg: its angle to the
    requested direction.
    """

    when_utc: dt.datetime
    lat_deg: float
    lon_deg: float
    alt_m: float
    utc_offset_min: int
    azimuth_deg: float
    elevation_deg: float
    error_deg: float

    @property
    def when_local(self) -> dt.datetime:
        """Aware local civil time."""
        return self.when_utc.astimezone(dt.timezone(dt.timedelta(minutes=self.utc_offset_min)))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(float(angular_distance(np.asarray(a, np.float64), np.asarray(b, np.float64))))


def _latitudes(sin_el: float, cos_el: float, cos_az: float, decl: np.ndarray) -> np.ndarray:
    """Latitudes ``(n, 2)`` (radians, NaN where impossible) with ``sin δ = sin φ sin el + cos φ cos el cos A``."""
    a, b = sin_el, cos_el * cos_az
    r = math.hypot(a, b)
    alpha = math.atan2(b, a)
    s = np.sin(decl) / max(r, 1e-12)
    ok = np.abs(s) <= 1.0
    base = np.arcsin(np.clip(s, -1.0, 1.0))
    phi = np.stack([base - alpha, math.pi - base - alpha], -1)
    phi = wrap_angle(phi)
    phi[~ok] = np.nan
    phi[np.abs(phi) > math.pi / 2] = np.nan
    return phi


def place_sun(
    direction: np.ndarray,
    rng: np.random.Generator,
    *,
    year: int = 2024,
    max_abs_lat_deg: float = 60.0,
    alt_range_m: tuple[float, float] = (0.0, 400.0),
    tol_deg: float = 1e-4,
) -> SolarFix:
    """A place and UTC time at which pvlib puts the sun at scene-frame ``direction`` (see module doc).

    ``direction``: unit ``(3,)``, x east, y down, z north, elevation above -0.5°. The day, the
    UTC second of the day, the altitude and the choice among valid latitudes are drawn from
    ``rng``. Raises :class:`InputError` for a sun below the horizon.
    """
    import pvlib

    target = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    az_deg, el_deg = solar_angles_deg(target)
    if el_deg < -0.5:
        raise InputError(f"place_sun: the sun is below the horizon (elevation {el_deg:.2f}°)")
    el, az = math.radians(max(el_deg, 0.0)), math.radians(az_deg)
    days = np.arange(1, 366)
    decl = np.asarray(pvlib.solarposition.declination_spencer71(days), np.float64)
    phi = _latitudes(math.sin(el), math.cos(el), math.cos(az), decl)
    lim = math.radians(max_abs_lat_deg)
    good = np.argwhere(np.abs(phi) <= lim)
    if len(good) == 0:  # e.g. a low sun due north: only high southern latitudes work; take the mildest
        finite = np.argwhere(np.isfinite(phi))
        if len(finite) == 0:
            raise InputError(f"place_sun: no latitude puts the sun at azimuth {az_deg:.1f}°, elevation {el_deg:.1f}°")
        best = np.min(np.abs(phi[tuple(finite.T)]))
        good = finite[np.abs(phi[tuple(finite.T)]) <= best + math.radians(2.0)]
    order = rng.permutation(len(good))
    alt = float(rng.uniform(*alt_range_m))
    second = int(rng.integers(0, 86400))
    for k in order[: min(len(order), 8)]:
        di, si = good[k]
        day, lat0, dec = int(days[di]), float(phi[di, si]), float(decl[di])
        when = dt.datetime(year, 1, 1, tzinfo=dt.timezone.utc) + dt.timedelta(days=day - 1, seconds=second)
        # first guess: hour angle (west positive) and the subsolar longitude from the equation of time
        cos_h = (math.sin(el) - math.sin(lat0) * math.sin(dec)) / max(math.cos(lat0) * math.cos(dec), 1e-12)
        sin_h = -math.sin(az) * math.cos(el) / max(math.cos(dec), 1e-12)
        hour_angle = math.degrees(math.atan2(sin_h, cos_h))
        eot_min = float(np.asarray(pvlib.solarposition.equation_of_time_spencer71(day)))
        utc_h = second / 3600.0
        lon_sub = -15.0 * (utc_h - 12.0 + eot_min / 60.0)
        x = np.array([math.degrees(lat0), wrap_angle(lon_sub + hour_angle, 360.0)])
        fix = _refine(x, when, alt, target, tol_deg)
        if fix is not None:
            return fix
    raise InputError(f"place_sun: could not place the sun at azimuth {az_deg:.2f}°, elevation {el_deg:.2f}°")


def _refine(x: np.ndarray, when: dt.datetime, alt: float, target: np.ndarray, tol_deg: float) -> SolarFix | None:
    """Gauss-Newton on (lat, lon) so that pvlib's sun at ``when`` matches ``target``."""

    def f(p: np.ndarray) -> np.ndarray:
        return solar_direction(*solar_position(when, float(p[0]), float(p[1]), alt))

    for _ in range(12):
        x[0] = float(np.clip(x[0], -89.0, 89.0))
        x[1] = wrap_angle(x[1], 360.0)
        cur = f(x)
        err = _angle(cur, target)
        if err < tol_deg:
            az, el = solar_position(when, float(x[0]), float(x[1]), alt)
            offset = int(np.clip(round(x[1] / 15.0), -12, 14)) * 60
            return SolarFix(when, float(x[0]), float(x[1]), alt, offset, az, el, err)
        h = 1e-3
        J = np.stack([(f(x + np.array([h, 0.0])) - cur) / h, (f(x + np.array([0.0, h])) - cur) / h], -1)
        step, *_ = np.linalg.lstsq(J, target - cur, rcond=None)
        x = x + np.clip(step, -10.0, 10.0)
    return None
