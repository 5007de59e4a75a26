"""Local NED metres to and from latitude/longitude around home (WGS-84,
tangent plane), written independently of lluavd's own conversion so the
tests check it rather than repeat it."""

import math

A = 6378137.0
F = 1 / 298.257223563
E2 = F * (2 - F)


def _radii(lat_deg):
    s = math.sin(math.radians(lat_deg))
    w = 1 - E2 * s * s
    return A * (1 - E2) / w ** 1.5, A / math.sqrt(w)


def global_from(home, north, east, down):
    """(lat, lon, alt AMSL) of a NED point relative to home (lat, lon, alt)."""
    m, n = _radii(home[0])
    lat = home[0] + math.degrees(north / m)
    lon = home[1] + math.degrees(east / (n * math.cos(math.radians(home[0]))))
    return lat, lon, home[2] - down


def ned_from(home, lat, lon, up_from_home):
    """[north, east, down] of a point given by lat/lon and height above home."""
    m, n = _radii(home[0])
    north = math.radians(lat - home[0]) * m
    east = math.radians(lon - home[1]) * n * math.cos(math.radians(home[0]))
    return [north, east, -up_from_home]
