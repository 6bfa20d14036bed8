"""GPS tags for synthetic photos: the true camera centres, put on Earth and blurred by a phone's GPS
error, written into the JPEGs' EXIF as cameras write them.

A scene's world frame (metres, z up) is taken as East-North-Up at :data:`ORIGIN`: world x is east,
y north, z up. Each photo's tag is its centre plus Gaussian noise of ``sigma`` metres per axis,
converted to WGS84 latitude, longitude and altitude (:func:`recon.geometry.gps.wgs84_from_enu`);
GPSHPositioningError says ``sigma``, as a phone states its accuracy. The EXIF layout follows CIPA
DC-008 (unsigned degree-minute-second rationals with N/S and E/W references), which
:func:`recon.geometry.gps.read_gps` reads back.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np
from PIL import Image, TiffImagePlugin

from recon.geometry.gps import wgs84_from_enu

#: where a synthetic scene's world origin is on Earth (WGS84 latitude, longitude, altitude)
ORIGIN = (48.8584, 2.2945, 35.0)

_GPS_IFD = 0x8825
_EXIF_IFD = 0x8769


@dataclass(frozen=True)
class GeoTag:
    """A photo's GPS tag: degrees, metres (altitude above sea level, horizontal accuracy); None: the
    tag leaves that field out, as many receivers do."""

    lat: float
    lon: float
    alt: float | None = None
    horizontal_error: float | None = None
    dop: float | None = None


def noisy_geotags(centres: dict[str, np.ndarray], sigma: float, seed: int,
                  origin: tuple[float, float, float] = ORIGIN) -> dict[str, GeoTag]:
    """Per photo name, the GPS tag of its true ``centre`` (world metres, ENU at ``origin``) moved by
    Gaussian noise of ``sigma`` metres per axis (drawn in name order from ``seed``)."""
    names = sorted(centres)
    rng = np.random.default_rng([seed, 16])
    enu = np.array([centres[n] for n in names], float) + rng.normal(0.0, sigma, (len(names), 3))
    lla = wgs84_from_enu(enu, origin)
    return {n: GeoTag(float(lat), float(lon), float(alt), sigma) for n, (lat, lon, alt) in zip(names, lla)}


def geotag_photos(images_dir: Path, centres: dict[str, np.ndarray], sigma: float, seed: int,
                  origin: tuple[float, float, float] = ORIGIN) -> dict[str, GeoTag]:
    """Write into each JPEG ``images_dir/<name>`` its :func:`noisy_geotags` tag (:func:`write_gps`)."""
    tags = noisy_geotags(centres, sigma, seed, origin)
    for name, tag in tags.items():
        write_gps(Path(images_dir) / name, tag)
    return tags


def add_gps(exif: Image.Exif, tag: GeoTag) -> None:
    """Fill ``exif``'s GPS IFD with ``tag``."""
    gps = exif.get_ifd(_GPS_IFD)
    gps[0] = b"\x02\x03\x00\x00"  # GPSVersionID 2.3
    gps[1], gps[2] = ("S" if tag.lat < 0 else "N"), _dms(tag.lat)
    gps[3], gps[4] = ("W" if tag.lon < 0 else "E"), _dms(tag.lon)
    if tag.alt is not None:
        gps[5], gps[6] = (1 if tag.alt < 0 else 0), _rational(abs(tag.alt), 1000)
    if tag.dop is not None:
        gps[11] = _rational(tag.dop, 100)  # GPSDOP
    if tag.horizontal_error is not None:
        gps[31] = _rational(tag.horizontal_error, 100)  # GPSHPositioningError


def write_gps(path: Path, tag: GeoTag) -> None:
    """Add (or replace) the GPS IFD of the JPEG at ``path``, keeping its other EXIF tags; only its EXIF
    segment is rewritten, so the compressed pixels stay byte-identical."""
    with Image.open(path) as img:
        exif = img.getexif()
    exif.get_ifd(_EXIF_IFD)  # loaded, so that tobytes() writes it back
    add_gps(exif, tag)
    _replace_exif_segment(Path(path), exif.tobytes())


def _replace_exif_segment(path: Path, payload: bytes) -> None:
    """Write ``payload`` (b"Exif\\0\\0" + TIFF) as the JPEG's APP1 segment, replacing an existing one."""
    data = path.read_bytes()
    if data[:2] != b"\xff\xd8":
        raise ValueError(f"{path}: not a JPEG")
    pos, exif = 2, None
    while data[pos] == 0xFF and data[pos + 1] not in (0xDA, 0xD9):  # the segments before the scan
        end = pos + 2 + struct.unpack(">H", data[pos + 2:pos + 4])[0]
        if data[pos + 1] == 0xE1 and data[pos + 4:pos + 10] == b"Exif\x00\x00" and exif is None:
            exif = pos, end
        pos = end
    app1 = b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
    a, b = exif if exif else (2, 2)
    path.write_bytes(data[:a] + app1 + data[b:])


def _rational(value: float, denominator: int) -> TiffImagePlugin.IFDRational:
    return TiffImagePlugin.IFDRational(Fraction(round(value * denominator), denominator))


def _dms(degrees: float) -> tuple:
    """Unsigned degrees, minutes, seconds (to 1e-4 s: 3 mm on the ground)."""
    degrees = abs(degrees)
    d = int(degrees)
    m = int((degrees - d) * 60)
    s = (degrees - d - m / 60) * 3600
    return (_rational(d, 1), _rational(m, 1), _rational(s, 10000))
