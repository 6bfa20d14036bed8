"""GPS positions: a photo's GPS tag (EXIF GPS IFD, drone XMP) and WGS84 <-> local East-North-Up metres.

EXIF GPSAltitude is a height above mean sea level; it is used as the WGS84 ellipsoid height. In a
local ENU frame that only shifts every height by the same amount (the geoid undulation at the site,
tens of metres): distances, directions and "up" are unaffected, absolute heights are not ellipsoidal.

XMP is read with regular expressions over the packet's text, not an XML parser: the few numeric
properties wanted need no parsing of the document, and an untrusted packet cannot expand entities.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

_GPS_IFD = 0x8825
# GPS IFD tag numbers (EXIF 2.32 / CIPA DC-008)
_LAT_REF, _LAT, _LON_REF, _LON, _ALT_REF, _ALT, _STATUS, _DOP, _H_ERROR = 1, 2, 3, 4, 5, 6, 9, 11, 31
#: drone XMP properties read (DJI's ``drone-dji:`` names; the same local names under other prefixes)
_XMP_FIELDS = {"RelativeAltitude": "relative_alt", "GimbalYawDegree": "gimbal_yaw",
               "GimbalPitchDegree": "gimbal_pitch", "GimbalRollDegree": "gimbal_roll",
               "RtkStdLon": "rtk_std_lon", "RtkStdLat": "rtk_std_lat"}
_XMP_NAMES = "|".join(_XMP_FIELDS)
_XMP_ATTRIBUTE = re.compile(rf'[\w.-]+:({_XMP_NAMES})\s*=\s*["\']([^"\']*)["\']')
_XMP_ELEMENT = re.compile(rf"<[\w.-]+:({_XMP_NAMES})>\s*([^<]*?)\s*</")


@dataclass(frozen=True)
class GpsTag:
    """Where a photo says it was taken. Angles in degrees, lengths in metres; None where absent."""

    lat: float
    lon: float
    alt: float | None  # EXIF GPSAltitude, above mean sea level
    dop: float | None  # EXIF GPSDOP (phones write their horizontal accuracy in metres there)
    horizontal_error: float | None  # EXIF GPSHPositioningError, metres
    relative_alt: float | None = None  # XMP (drones): height above the take-off point
    gimbal_yaw: float | None = None  # XMP (drones): camera gimbal angles
    gimbal_pitch: float | None = None
    gimbal_roll: float | None = None
    rtk_std_lon: float | None = None  # XMP (RTK drones): standard deviation of the position, metres
    rtk_std_lat: float | None = None


def read_gps(exif, xmp: bytes | str | None, source: str) -> GpsTag | None:
    """The GPS tag of a photo from its Pillow ``Image.Exif`` and XMP packet, or None without a
    usable position. A position out of range or marked void is ignored with a warning naming
    ``source`` (the photo); (0, 0) is what cameras without a fix write, and is ignored silently."""
    gps = dict(exif.get_ifd(_GPS_IFD)) if hasattr(exif, "get_ifd") else {}
    if _LAT not in gps or _LON not in gps:
        return None
    lat = _degrees(gps.get(_LAT), gps.get(_LAT_REF), "S")
    lon = _degrees(gps.get(_LON), gps.get(_LON_REF), "W")
    if _text(gps.get(_STATUS)) == "V":
        log.warning("%s: EXIF GPS marks its position void (GPSStatus V); ignored", source)
        return None
    if lat is None or lon is None or not (abs(lat) <= 90 and abs(lon) <= 180):
        log.warning("%s: EXIF GPS position is not a valid latitude/longitude (%r, %r); ignored",
                    source, gps.get(_LAT), gps.get(_LON))
        return None
    if lat == 0 and lon == 0:
        return None
    alt = _finite(gps.get(_ALT))
    if alt is not None and _int(gps.get(_ALT_REF)) == 1:  # 1: below sea level
        alt = -alt
    return GpsTag(lat=lat, lon=lon, alt=alt, dop=_positive(gps.get(_DOP)),
                  horizontal_error=_positive(gps.get(_H_ERROR)), **read_xmp_drone(xmp))


def read_xmp_drone(xmp: bytes | str | None) -> dict[str, float]:
    """The drone properties of an XMP packet present in it (``relative_alt``, ``gimbal_yaw``, ...)."""
    if not xmp:
        return {}
    text = xmp.decode("utf-8", "replace") if isinstance(xmp, bytes) else xmp
    found = {}
    for pattern in (_XMP_ATTRIBUTE, _XMP_ELEMENT):
        for name, value in pattern.findall(text):
            number = _finite(value)
            if number is not None:
                found.setdefault(_XMP_FIELDS[name], number)
    return found


def enu_from_wgs84(lat_lon_alt: np.ndarray, origin: tuple[float, float, float]) -> np.ndarray:
    """East-North-Up metres (N, 3) of WGS84 (lat, lon, alt) positions (N, 3), in the frame tangent at
    ``origin`` (lat, lon, alt)."""
    import pycolmap

    transform = pycolmap.GPSTransform(pycolmap.GPSTransformEllipsoid.WGS84)
    return transform.ellipsoid_to_enu(np.asarray(lat_lon_alt, dtype=float).reshape(-1, 3), *origin)


def wgs84_from_enu(enu: np.ndarray, origin: tuple[float, float, float]) -> np.ndarray:
    """WGS84 (lat, lon, alt) (N, 3) of East-North-Up positions (N, 3) in the frame at ``origin``."""
    import pycolmap

    transform = pycolmap.GPSTransform(pycolmap.GPSTransformEllipsoid.WGS84)
    return transform.enu_to_ellipsoid(np.asarray(enu, dtype=float).reshape(-1, 3), *origin)


def _degrees(dms, ref, negative: str) -> float | None:
    """Decimal degrees of an EXIF (degrees, minutes, seconds) triple and its N/S or E/W reference."""
    try:
        parts = [float(v) for v in (dms if isinstance(dms, (tuple, list)) else [dms])]
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    if not 1 <= len(parts) <= 3 or not all(math.isfinite(p) for p in parts):
        return None
    value = sum(p / 60**i for i, p in enumerate(parts))
    return -value if _text(ref).upper() == negative else value


def _text(value) -> str:
    if isinstance(value, bytes):
        value = value.decode("ascii", "replace")
    return str(value).strip("\x00 ") if value is not None else ""


def _int(value) -> int | None:
    if isinstance(value, bytes):
        return value[0] if value else None
    try:
        return int(value)
    except (TypeError, ValueError):
        return None


def _finite(value) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return number if math.isfinite(number) else None


def _positive(value) -> float | None:
    number = _finite(value)
    return number if number is not None and number > 0 else None
