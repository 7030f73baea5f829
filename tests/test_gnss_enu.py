"""Local ENU, GPS time and SPAN attitude in ENU."""

import numpy as np
import pytest

from lidar3d.errors import GnssError
from lidar3d.gnss import (
    GeodeticOrigin,
    LocalEnu,
    R_enu_vehicle_from_span,
    gps_to_unix_ns,
    unix_ns_to_gps,
)

# Published geodetic -> ENU vectors (shared/reference/gnss-and-metrics.md section 2):
# origin, point, published ENU, published precision (m).
PUBLISHED = [
    # MathWorks geodetic2enu doc: Zermatt -> Matterhorn
    ((46.017, 7.750, 1673.0), (45.976, 7.658, 4531.0), (-7134.8, -4556.3, 2852.4), 0.05),
    # Octave mapping geodetic2enu doc
    ((42.0, -82.0, 200.0), (42.002, -81.998, 1000.0), (165.72, 222.18, 799.99), 0.005),
    # EPSG Guidance Note 7-2, topocentric example (EPSG:15594)
    (
        (55.0, 5.0, 200.0),
        (53 + 48 / 60 + 33.820 / 3600, 2 + 7 / 60 + 46.380 / 3600, 73.0),
        (-189013.869, -128642.040, -4220.171),
        0.0005,
    ),
]


@pytest.mark.parametrize("origin,point,expected,precision", PUBLISHED)
def test_enu_reproduces_published_vectors(origin, point, expected, precision):
    enu = LocalEnu(GeodeticOrigin(*origin))
    got = enu.to_enu(*point)[0]
    assert got == pytest.approx(expected, abs=precision)


def _ecef_closed_form(lat_deg, lon_deg, h):
    """WGS84 geodetic -> ECEF (e.g. Hofmann-Wellenhof et al., GNSS, eq. 2.61), independent of pyproj."""
    a = 6378137.0
    f = 1.0 / 298.257223563
    e2 = f * (2.0 - f)
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    return np.stack(
        [(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1 - e2) + h) * np.sin(lat)],
        axis=-1,
    )


def _enu_independent(origin, lat, lon, h):
    p0 = _ecef_closed_form(*origin)
    p = _ecef_closed_form(lat, lon, h)
    lat0, lon0 = np.radians(origin[0]), np.radians(origin[1])
    up = np.array([np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)])
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    d = p - p0
    return np.stack([d @ east, d @ north, d @ up], axis=-1)


def test_enu_agrees_with_independent_route_to_a_millimetre():
    rng = np.random.default_rng(3)
    for origin in [(51.1504, -114.0307, 1080.0), (-33.9, 151.2, 40.0), (43.40, -80.47, 290.0), (78.2, 15.6, 10.0)]:
        enu = LocalEnu(GeodeticOrigin(*origin))
        lat = origin[0] + rng.uniform(-0.05, 0.05, 200)  # up to ~5 km away
        lon = origin[1] + rng.uniform(-0.05, 0.05, 200)
        h = origin[2] + rng.uniform(-50, 200, 200)
        expected = _enu_independent(origin, lat, lon, h)
        assert np.abs(enu.to_enu(lat, lon, h) - expected).max() < 1e-3
        lat_back, lon_back, h_back = enu.to_geodetic(expected)
        assert np.abs(lat_back - lat).max() < 1e-10 and np.abs(lon_back - lon).max() < 1e-10
        assert np.abs(h_back - h).max() < 1e-4


def test_origin_maps_to_zero_and_distances_are_preserved():
    enu = LocalEnu(GeodeticOrigin(51.15, -114.03, 1080.0))
    assert np.abs(enu.to_enu(51.15, -114.03, 1080.0)).max() < 1e-9
    a, b = enu.to_enu([51.16, 51.14], [-114.0, -114.05], [1100.0, 1050.0])
    ecef = _ecef_closed_form(np.array([51.16, 51.14]), np.array([-114.0, -114.05]), np.array([1100.0, 1050.0]))
    assert np.linalg.norm(a - b) == pytest.approx(np.linalg.norm(ecef[0] - ecef[1]), abs=1e-6)


def test_origin_rejects_bad_values():
    with pytest.raises(GnssError, match=r"^ENU origin: latitude_deg 91.0 outside \[-90, 90\]$"):
        GeodeticOrigin(91.0, 0.0, 0.0)
    with pytest.raises(GnssError, match=r"^ENU origin: longitude_deg nan is not finite$"):
        GeodeticOrigin(10.0, float("nan"), 0.0)
    with pytest.raises(GnssError, match=r"longitude_deg 180.5 outside \[-180, 180\]"):
        GeodeticOrigin(10.0, 180.5, 0.0)
    with pytest.raises(GnssError, match=r"height_ellipsoid_m 25000.0 outside \[-1000, 20000\] m"):
        GeodeticOrigin(10.0, 10.0, 25000.0)
    with pytest.raises(GnssError, match="height_ellipsoid_m inf is not finite"):
        GeodeticOrigin(10.0, 10.0, float("inf"))


def test_local_level_rotation_far_from_origin():
    enu = LocalEnu(GeodeticOrigin(45.0, 10.0, 0.0))
    assert np.allclose(enu.R_enu_local(45.0, 10.0)[0], np.eye(3), atol=1e-15)
    # 0.01 deg of latitude north: local level is tilted about east by 0.01 deg
    R = enu.R_enu_local(45.01, 10.0)[0]
    up_local = R @ [0, 0, 1]
    assert np.degrees(np.arctan2(up_local[1], up_local[2])) == pytest.approx(0.01, abs=1e-9)


@pytest.mark.parametrize(
    "week,seconds,unix",
    [
        (2158, 95593.00, 1621218775.00),  # UrbanNav ground truth UTCTime column
        (2269, 129755.02, 1688385737.02),  # 2023-07-03T12:02:17.02Z
        (2209, 490558.0, 1652458540.0),  # 2022-05-13T16:15:40Z
    ],
)
def test_gps_to_unix_test_vectors(week, seconds, unix):
    stamp = gps_to_unix_ns(week, seconds)
    assert stamp == round(unix * 1e9)
    assert gps_to_unix_ns(week, seconds, leap_seconds=17) == stamp + 1_000_000_000
    assert gps_to_unix_ns(week, seconds, time_offset_s=0.035) == stamp + 35_000_000
    back_week, back_seconds = unix_ns_to_gps(stamp)
    assert int(back_week) == week and float(back_seconds) == pytest.approx(seconds, abs=1e-9)


def test_gps_time_keeps_nanoseconds_of_body_time():
    stamps = gps_to_unix_ns([1264, 1264], [144088.002284950, 144088.0])
    assert stamps.dtype == np.int64
    assert int(stamps[0] - stamps[1]) == 2_284_950


def test_span_attitude_axes_in_enu():
    # azimuth 90 deg: forward (vehicle +y) points east; pitch > 0 raises the nose; roll > 0 lowers the right side
    R = R_enu_vehicle_from_span(0.0, 0.0, 90.0)
    assert np.allclose(R @ [0, 1, 0], [1, 0, 0], atol=1e-12)
    R = R_enu_vehicle_from_span(0.0, 10.0, 0.0)
    assert (R @ [0, 1, 0])[2] > 0
    R = R_enu_vehicle_from_span(10.0, 0.0, 0.0)
    assert (R @ [1, 0, 0])[2] < 0
    # equivalent REP-103 form: R_enu_base = Rz(90 - az) Ry(-pitch) Rx(roll) with base = vehicle rotated
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    R_vehicle_base = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], float)
    for roll, pitch, azimuth in rng.uniform([-30, -30, 0], [30, 30, 360], (20, 3)):
        R_enu_base = Rotation.from_euler("ZYX", [90 - azimuth, -pitch, roll], degrees=True).as_matrix()
        assert np.allclose(R_enu_vehicle_from_span(roll, pitch, azimuth) @ R_vehicle_base, R_enu_base, atol=1e-12)
