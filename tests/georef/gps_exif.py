"""Test helpers: write EXIF GPS into a JPEG without re-encoding its pixels."""

from __future__ import annotations

import struct
from fractions import Fraction
from pathlib import Path

from PIL import Image, TiffImagePlugin

GPS_IFD = 0x8825


def _rational(value: float, denominator: int) -> TiffImagePlugin.IFDRational:
    return TiffImagePlugin.IFDRational(Fraction(round(value * denominator), denominator))


def _dms(degrees: float) -> tuple:
    degrees = abs(degrees)
    d = int(degrees)
    m = int((degrees - d) * 60)
    s = (degrees - d - m / 60) * 3600
    return (_rational(d, 1), _rational(m, 1), _rational(s, 10000))


def gps_ifd(exif: Image.Exif, lat: float, lon: float, alt: float | None = None,
            h_error: float | None = None, dop: float | None = None) -> None:
    """Fill ``exif``'s GPS IFD as cameras do: unsigned DMS rationals with N/S and E/W references."""
    gps = exif.get_ifd(GPS_IFD)
    gps[0] = b"\x02\x03\x00\x00"  # GPSVersionID 2.3
    gps[1], gps[2] = ("S" if lat < 0 else "N"), _dms(lat)
    gps[3], gps[4] = ("W" if lon < 0 else "E"), _dms(lon)
    if alt is not None:
        gps[5], gps[6] = (1 if alt < 0 else 0), _rational(abs(alt), 1000)
    if dop is not None:
        gps[11] = _rational(dop, 100)
    if h_error is not None:
        gps[31] = _rational(h_error, 100)


def set_gps(path: Path, lat: float, lon: float, alt: float | None, h_error: float | None = None) -> None:
    """Add a GPS IFD to the JPEG at ``path`` (keeping its other EXIF tags), rewriting only its EXIF
    segment: the compressed pixels stay byte-identical."""
    with Image.open(path) as img:
        exif = img.getexif()
    exif.get_ifd(0x8769)  # load the Exif sub-IFD so tobytes() writes it back
    gps_ifd(exif, lat, lon, alt, h_error)
    replace_exif_segment(path, exif.tobytes())


def replace_exif_segment(path: Path, payload: bytes) -> None:
    """Write ``payload`` (b"Exif\\0\\0" + TIFF) as the JPEG's APP1 segment, replacing an existing one."""
    data = Path(path).read_bytes()
    assert data[:2] == b"\xff\xd8", f"{path}: not a JPEG"
    pos, segments = 2, []
    while data[pos] == 0xFF and data[pos + 1] not in (0xDA, 0xD9):  # markers up to start-of-scan
        length = struct.unpack(">H", data[pos + 2:pos + 4])[0]
        segments.append((pos, pos + 2 + length, data[pos + 1], data[pos + 4:pos + 10]))
        pos += 2 + length
    app1 = b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
    exif = [(a, b) for a, b, marker, head in segments if marker == 0xE1 and head == b"Exif\x00\x00"]
    if exif:
        a, b = exif[0]
        out = data[:a] + app1 + data[b:]
    else:
        out = data[:2] + app1 + data[2:]
    Path(path).write_bytes(out)
