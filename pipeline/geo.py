"""Local flat-earth conversion between WGS-84 latitude/longitude and NED metres.

Accurate to well under a metre over the few kilometres of a sea trial (Fossen 2021, sec. 2.5.2).
"""

from __future__ import annotations

import numpy as np

_A = 6378137.0              # WGS-84 semi-major axis [m]
_E2 = 6.69437999014e-3      # WGS-84 first eccentricity squared [-]


def _radii(lat0_deg: float) -> tuple[float, float]:
    lat0 = np.radians(lat0_deg)
    s2 = np.sin(lat0) ** 2
    r_n = _A / np.sqrt(1 - _E2 * s2)                 # prime vertical radius [m]
    r_m = r_n * (1 - _E2) / (1 - _E2 * s2)           # meridian radius [m]
    return r_m, r_n * np.cos(lat0)


def latlon_to_ned(lat_deg, lon_deg, lat0_deg: float, lon0_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """North and east offsets [m] of (lat, lon) [deg] from the origin (lat0, lon0) [deg].

    Parameters
    ----------
    lat_deg, lon_deg : array_like
        WGS-84 latitude and longitude [deg] of the points.
    lat0_deg, lon0_deg : float
        Latitude and longitude [deg] of the NED origin.

    Returns
    -------
    x_n, y_e : numpy.ndarray
        North and east offsets [m] (Fossen 2021, sec. 2.5.2).
    """
    r_m, r_e = _radii(lat0_deg)
    x_n = np.radians(np.asarray(lat_deg, float) - lat0_deg) * r_m
    y_e = np.radians(np.asarray(lon_deg, float) - lon0_deg) * r_e
    return x_n, y_e


def ned_to_latlon(x_n, y_e, lat0_deg: float, lon0_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Latitude and longitude [deg] of the NED offsets (x_n, y_e) [m] from (lat0, lon0) [deg].

    The inverse of :func:`latlon_to_ned`.

    Parameters
    ----------
    x_n, y_e : array_like
        North and east offsets [m] from the origin.
    lat0_deg, lon0_deg : float
        Latitude and longitude [deg] of the NED origin.

    Returns
    -------
    lat, lon : numpy.ndarray
        WGS-84 latitude and longitude [deg].
    """
    r_m, r_e = _radii(lat0_deg)
    lat = lat0_deg + np.degrees(np.asarray(x_n, float) / r_m)
    lon = lon0_deg + np.degrees(np.asarray(y_e, float) / r_e)
    return lat, lon


def wrap_pi(angle):
    """Wrap angles [rad] to (-pi, pi].

    Parameters
    ----------
    angle : array_like
        Angles [rad], any range.

    Returns
    -------
    numpy.ndarray
        The same angles [rad] in (-pi, pi].
    """
    a = np.asarray(angle, float)
    return np.pi - np.mod(np.pi - a, 2 * np.pi)
