"""Ground control points: OpenDroneMap / OpenSfM's ``gcp_list.txt`` and its coordinate systems.

The format (the one drone users already write, e.g. with ODM's GCP editor)::

    EPSG:32632                                   # first line: the coordinate system
    464310.12 5248101.55 412.30 1021.5 644.0 DJI_0012.JPG gcp_a
    464310.12 5248101.55 412.30  880.0 610.5 DJI_0013.JPG gcp_a
    ...

then one line per observation: ``geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extra ...]``,
separated by spaces or tabs. The coordinate system line is a PROJ string, ``EPSG:<code>``,
``WGS84`` (x longitude, y latitude, z ellipsoidal height: x before y, as ODM reads every CRS),
``WGS84 UTM <zone><N|S>``, or ``ENU``: local metric coordinates (x east, y north, z up), e.g. a site
survey that is not tied to the Earth. Observations of one point share its name, or, without a
name, its coordinates. Blank lines and lines starting with ``#`` are skipped.

Pixel positions are kept as ODM writes them: whole numbers at pixel centres (the top-left pixel's
centre is (0, 0)). Heights of a
projected CRS without a vertical component (UTM) are taken as ellipsoidal heights, as for EXIF GPS.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: the CRS line of a file whose coordinates are local East-North-Up metres
LOCAL_ENU = "ENU"
_UTM = re.compile(r"WGS84\s+UTM\s+(\d{1,2})\s*([NS])", re.IGNORECASE)
_WGS84_2D, _WGS84_3D = "EPSG:4326", "EPSG:4979"


class GcpFileError(ValueError):
    """A GCP file that cannot be read; the message names the file and line."""


@dataclass(frozen=True)
class Observation:
    """Where a photo sees a point: pixel coordinates, the top-left pixel's centre at (0, 0)."""

    image: str
    x: float
    y: float


@dataclass(frozen=True, eq=False)
class ControlPoint:
    """A surveyed point: its coordinates in the file's CRS and the photos that see it."""

    name: str
    position: np.ndarray  # (3,) as written in the file
    observations: tuple[Observation, ...]


@dataclass(frozen=True, eq=False)
class GcpList:
    crs: str  # the file's first line
    points: list[ControlPoint]

    @property
    def local(self) -> bool:
        """Whether the coordinates are local ENU metres, not tied to the Earth."""
        return self.crs.strip().upper() == LOCAL_ENU


def read_gcp_list(path: str | Path) -> GcpList:
    """Parse a ``gcp_list.txt``; raises :class:`GcpFileError` naming the line at fault."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise GcpFileError(f"{path}: cannot read the GCP file ({exc})") from None
    numbered = [(k, line.strip()) for k, line in enumerate(lines, start=1)
                if line.strip() and not line.lstrip().startswith("#")]
    if not numbered:
        raise GcpFileError(f"{path}: empty; the first line names the coordinate system (e.g. EPSG:32632)")
    (_, crs), rows = numbered[0], numbered[1:]
    _check_crs(crs, path)
    points: dict[str, tuple[np.ndarray, list[Observation]]] = {}
    for number, line in rows:
        fields = line.split()
        where = f"{path}:{number}"
        if len(fields) < 6:
            raise GcpFileError(f"{where}: expected 'geo_x geo_y geo_z im_x im_y image_name [gcp_name]', "
                               f"got {len(fields)} field(s)")
        try:
            values = [float(v) for v in fields[:5]]
        except ValueError:
            raise GcpFileError(f"{where}: the first five fields must be numbers: {' '.join(fields[:5])}") from None
        if not all(math.isfinite(v) for v in values):
            raise GcpFileError(f"{where}: coordinates must be finite (a GCP without a height cannot be used: "
                               "give its height)")
        position = np.array(values[:3])
        name = fields[6] if len(fields) > 6 else " ".join(fields[:3])
        known, observed = points.setdefault(name, (position, []))
        if not np.allclose(known, position, rtol=0, atol=1e-9 * max(1.0, float(np.abs(position).max()))):
            raise GcpFileError(f"{where}: point '{name}' was given other coordinates on an earlier line")
        observed.append(Observation(fields[5], values[3], values[4]))
    if not points:
        raise GcpFileError(f"{path}: no observations after the coordinate system line")
    return GcpList(crs, [ControlPoint(name, pos, tuple(obs)) for name, (pos, obs) in points.items()])


def to_wgs84(crs: str, xyz: np.ndarray) -> np.ndarray:
    """(lat, lon, height) (N, 3) of positions (N, 3) written in ``crs`` (a GCP file's first line,
    not ``ENU``)."""
    from pyproj import Transformer

    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    transformer = Transformer.from_crs(_pyproj_crs(crs), _WGS84_3D, always_xy=True)
    lon, lat, height = transformer.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    return np.column_stack([lat, lon, height])


def _pyproj_crs(line: str):
    from pyproj import CRS

    text = line.strip()
    if text.upper() == "WGS84":
        return CRS.from_user_input(_WGS84_2D)
    utm = _UTM.fullmatch(text)
    if utm:
        zone, hemisphere = int(utm.group(1)), utm.group(2).upper()
        return CRS.from_epsg((32600 if hemisphere == "N" else 32700) + zone)
    return CRS.from_user_input(text)


def _check_crs(line: str, path: Path) -> None:
    if line.strip().upper() == LOCAL_ENU:
        return
    try:
        _pyproj_crs(line)
    except Exception as exc:  # pyproj's CRSError, or a bad UTM zone
        raise GcpFileError(f"{path}:1: '{line}' is not a coordinate system pyproj knows ({exc}); write e.g. "
                           "EPSG:32632, WGS84, 'WGS84 UTM 32N', a PROJ string, or ENU for local metres") from None
