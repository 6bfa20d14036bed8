"""The local East-North-Up frame of a georeferenced model as UTM easting, northing and height.

Over a capture's extent the map from local ENU to UTM is a similarity up to millimetres: a rotation
about the vertical by the grid convergence, the projection's point scale factor (0.9996 to about
1.0004) and a shift. The residual is what a similarity cannot follow: the ellipsoid curving away
below a tangent plane (about 8 cm at 1 km from the origin) and the scale factor's change across the
extent. :func:`enu_to_utm` fits that similarity to ENU points converted by pyproj and states its
largest error, so a model stays rigid (the cameras keep their poses) and the error is known.

Coordinates are UTM minus an offset of whole kilometres (as OpenDroneMap writes them): 32-bit floats,
which PLY, glTF and most viewers use, hold full UTM northings only to about half a metre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recon.geometry.gps import wgs84_from_enu
from recon.geometry.transforms import umeyama


@dataclass(frozen=True)
class UtmFrame:
    epsg: int  # WGS 84 / UTM zone: 326zz north, 327zz south
    zone: str  # e.g. "33N"
    offset: tuple[float, float, float]  # subtracted from (easting, northing, height), metres
    from_enu: object  # recon.geometry.transforms.Similarity: x_utm - offset = s R x_enu + t
    max_error_m: float  # the similarity's largest error over the extent it was fitted on


def utm_zone(lat: float, lon: float) -> tuple[int, str]:
    """The EPSG code and name of the WGS 84 UTM zone holding (lat, lon) (no Norway/Svalbard exceptions)."""
    number = min(int(math.floor((lon + 180.0) / 6.0)) + 1, 60)
    north = lat >= 0
    return (32600 if north else 32700) + number, f"{number}{'N' if north else 'S'}"


def enu_to_utm(origin: tuple[float, float, float], extent: np.ndarray) -> UtmFrame:
    """The similarity from the local ENU frame at ``origin`` (lat, lon, alt) to the UTM zone of the
    origin minus whole kilometres, fitted on a 5 x 5 x 3 grid spanning ``extent`` (N, 3 ENU points,
    e.g. the camera centres) widened by 10 %."""
    from pyproj import Transformer

    epsg, zone = utm_zone(origin[0], origin[1])
    lo, hi = extent.min(axis=0), extent.max(axis=0)
    pad = 0.1 * (hi - lo) + 1.0
    axes = [np.linspace(a - p, b + p, n) for a, b, p, n in zip(lo, hi, pad, (5, 5, 3), strict=True)]
    enu = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    lla = wgs84_from_enu(enu, origin)
    to_utm = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
    easting, northing = to_utm.transform(lla[:, 1], lla[:, 0])
    utm = np.column_stack([easting, northing, lla[:, 2]])
    centre = to_utm.transform(origin[1], origin[0])
    offset = (1000.0 * math.floor(centre[0] / 1000.0), 1000.0 * math.floor(centre[1] / 1000.0), 0.0)
    local = utm - np.array(offset)
    sim = umeyama(enu, local)
    error = float(np.linalg.norm(sim.apply(enu) - local, axis=1).max())
    return UtmFrame(epsg=epsg, zone=zone, offset=offset, from_enu=sim, max_error_m=error)
