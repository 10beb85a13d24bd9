"""Solar placement: pvlib at the chosen place and time puts the sun at the requested direction."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pandas as pd
import pvlib
import pytest

from solidkit.errors import InputError
from solidkit.synth.solar import place_sun, solar_angles_deg, solar_direction, utc_offset_text


def _pvlib_direction(when: dt.datetime, lat: float, lon: float, alt: float) -> np.ndarray:
    sp = pvlib.solarposition.get_solarposition(pd.DatetimeIndex([when]), lat, lon, altitude=alt)
    return solar_direction(float(sp["azimuth"].iloc[0]), float(sp["apparent_elevation"].iloc[0]))


def test_frames() -> None:
    # scene frame x east, y down, z north; azimuth clockwise from north
    assert solar_angles_deg(np.array([1.0, 0.0, 0.0])) == pytest.approx((90.0, 0.0))
    assert solar_angles_deg(np.array([0.0, 0.0, 1.0])) == pytest.approx((0.0, 0.0))
    assert solar_angles_deg(np.array([0.0, -1.0, 1.0]))[1] == pytest.approx(45.0)
    for az, el in [(0.0, 10.0), (123.4, 56.7), (271.0, 3.0)]:
        assert solar_angles_deg(solar_direction(az, el)) == pytest.approx((az, el))
    assert utc_offset_text(-330) == "-05:30" and utc_offset_text(120) == "+02:00"


@pytest.mark.parametrize(
    "az,el",
    [(0.0, 5.0), (180.0, 5.0), (90.0, 89.5), (270.0, 85.0), (10.0, 45.0), (200.0, 0.3), (300.0, 30.0), (45.0, 70.0)],
)
def test_place_sun_reproduces_the_direction_with_pvlib(az: float, el: float) -> None:
    target = solar_direction(az, el)
    fix = place_sun(target, np.random.default_rng(int(az * 10 + el)))
    assert fix.when_utc.microsecond == 0 and fix.when_utc.utcoffset() == dt.timedelta(0)  # EXIF has whole seconds
    assert -90.0 <= fix.lat_deg <= 90.0 and -180.0 <= fix.lon_deg < 180.0
    got = _pvlib_direction(fix.when_utc, fix.lat_deg, fix.lon_deg, fix.alt_m)
    err = math.degrees(math.acos(min(1.0, float(got @ target))))
    assert err < 1e-3, err
    assert fix.error_deg < 1e-3
    # local civil time: the nominal zone of the longitude, so the local clock is daytime-like
    assert abs(fix.utc_offset_min / 60 - fix.lon_deg / 15) <= 0.5 + 1e-9 or fix.utc_offset_min in (-720, 840)


def test_place_sun_prefers_moderate_latitudes_and_refuses_night() -> None:
    rng = np.random.default_rng(1)
    lats = [place_sun(solar_direction(a, e), rng).lat_deg for a, e in [(90.0, 30.0), (150.0, 60.0), (250.0, 20.0)]]
    assert all(abs(v) <= 60.0 + 1e-6 for v in lats)
    # a sun 88° high exists only in the tropics
    assert abs(place_sun(solar_direction(30.0, 88.0), rng).lat_deg) < 23.44 + 2.1
    with pytest.raises(InputError):
        place_sun(solar_direction(0.0, -5.0), rng)
