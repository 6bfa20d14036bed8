"""EXIF reading for georeferencing: GPS positions, drone XMP, and focal lengths that are refused."""

from __future__ import annotations

import logging
import math

import pytest
from PIL import Image, TiffImagePlugin

from recon.geometry.gps import read_gps, read_xmp_drone
from recon.sparse.photos import inspect_photo
from recon.synth.geotags import GeoTag, add_gps, write_gps

EXIF_IFD, FOCAL, FOCAL_35 = 0x8769, 0x920A, 0xA405
FP_XRES, FP_YRES, FP_UNIT = 0xA20E, 0xA20F, 0xA210
W, H = 320, 240


def _jpeg(path, exif: Image.Exif | None = None, xmp: bytes | None = None):
    kwargs = {"exif": exif} if exif is not None else {}
    if xmp is not None:
        kwargs["xmp"] = xmp
    Image.new("RGB", (W, H), (90, 120, 150)).save(path, "JPEG", **kwargs)
    return path


def _focal_exif(focal=None, f35=None, resolution=False) -> Image.Exif:
    exif = Image.Exif()
    sub = exif.get_ifd(EXIF_IFD)
    if focal is not None:
        sub[FOCAL] = focal
    if f35 is not None:
        sub[FOCAL_35] = f35
    if resolution:  # W pixels across a 36 mm sensor
        sub[FP_XRES] = sub[FP_YRES] = TiffImagePlugin.IFDRational(W * 10, 36)
        sub[FP_UNIT] = 3
    return exif


@pytest.mark.parametrize("tags", [
    {"f35": -35}, {"f35": 1_000_000_000}, {"f35": 1},  # 1 mm equivalent: 175 degrees
    {"focal": -4.3}, {"focal": 0.0}, {"focal": math.nan},  # no sensor size: only the sign can be judged
    {"focal": -20.0, "resolution": True}, {"focal": 1e9, "resolution": True}, {"focal": math.nan, "resolution": True},
    {"focal": 0.0, "resolution": True}, {"f35": 1_000_000_000, "focal": 1e9, "resolution": True},
])
def test_implausible_focal_lengths_are_ignored_with_a_warning_naming_the_photo(tmp_path, caplog, tags):
    path = _jpeg(tmp_path / "bad_focal.jpg", _focal_exif(**tags))
    with caplog.at_level(logging.WARNING):
        info = inspect_photo(path, path.name)
    assert info.focal_px is None
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and str(path) in warned[0] and "ignored" in warned[0], warned


@pytest.mark.parametrize("tags, expected", [
    ({"f35": 35}, 35 / 43.267 * math.hypot(W, H)),
    ({"focal": 36.0, "resolution": True}, W),  # a 36 mm lens on a 36 mm sensor: focal = width
    # a broken 35 mm tag does not hide a good FocalLength (the broken one is still reported)
    ({"f35": 1_000_000_000, "focal": 18.0, "resolution": True}, W / 2),
])
def test_plausible_focal_lengths_are_kept(tmp_path, caplog, tags, expected):
    path = _jpeg(tmp_path / "good.jpg", _focal_exif(**tags))
    with caplog.at_level(logging.WARNING):
        info = inspect_photo(path, path.name)
    assert info.focal_px == pytest.approx(expected, rel=1e-3)
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == (1 if tags.get("f35") == 1_000_000_000 else 0), warned


def test_unknown_35mm_focal_is_silent(tmp_path, caplog):
    """FocalLengthIn35mmFilm 0 is EXIF's "unknown": no prior and nothing to warn about."""
    path = _jpeg(tmp_path / "unknown.jpg", _focal_exif(f35=0))
    with caplog.at_level(logging.WARNING):
        assert inspect_photo(path, path.name).focal_px is None
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


@pytest.mark.parametrize("lat, lon, alt", [(52.518917, 13.400294, 27.0), (-33.856784, -151.215297, -12.5)])
def test_gps_position_round_trip(tmp_path, lat, lon, alt):
    exif = _focal_exif(f35=28)
    add_gps(exif, GeoTag(lat, lon, alt, horizontal_error=3.5, dop=1.2))
    tag = inspect_photo(_jpeg(tmp_path / "gps.jpg", exif), "gps.jpg").gps
    assert tag is not None
    # DMS seconds are stored to 1e-4": 3 mm
    assert (tag.lat, tag.lon, tag.alt) == pytest.approx((lat, lon, alt), abs=1e-7)
    assert (tag.horizontal_error, tag.dop) == pytest.approx((3.5, 1.2))
    assert tag.relative_alt is None and tag.gimbal_yaw is None


def test_write_gps_keeps_pixels_and_other_tags(tmp_path):
    path = _jpeg(tmp_path / "photo.jpg", _focal_exif(f35=35))
    before = inspect_photo(path, path.name)
    with Image.open(path) as img:
        pixels = img.tobytes()
    write_gps(path, GeoTag(48.1, 11.5, 520.0, horizontal_error=3.0))
    after = inspect_photo(path, path.name)
    with Image.open(path) as img:
        assert img.tobytes() == pixels
    assert after.focal_px == before.focal_px
    assert (after.gps.lat, after.gps.lon, after.gps.alt, after.gps.horizontal_error) == pytest.approx(
        (48.1, 11.5, 520.0, 3.0))


def test_no_gps_void_and_zero_fixes(tmp_path, caplog):
    assert inspect_photo(_jpeg(tmp_path / "none.jpg"), "none.jpg").gps is None
    zero = _focal_exif()
    add_gps(zero, GeoTag(0.0, 0.0, 0.0))  # what cameras without a fix write
    assert inspect_photo(_jpeg(tmp_path / "zero.jpg", zero), "zero.jpg").gps is None
    void = _focal_exif()
    add_gps(void, GeoTag(10.0, 20.0, 5.0))
    void.get_ifd(0x8825)[9] = "V"
    with caplog.at_level(logging.WARNING):
        assert inspect_photo(_jpeg(tmp_path / "void.jpg", void), "void.jpg").gps is None
    assert any("void.jpg" in r.getMessage() and "void" in r.getMessage() for r in caplog.records)


def test_out_of_range_position_is_ignored_with_a_warning(tmp_path, caplog):
    exif = _focal_exif()
    add_gps(exif, GeoTag(10.0, 20.0, 5.0))
    exif.get_ifd(0x8825)[2] = (TiffImagePlugin.IFDRational(95, 1), TiffImagePlugin.IFDRational(0, 1),
                               TiffImagePlugin.IFDRational(0, 1))
    path = _jpeg(tmp_path / "lat95.jpg", exif)
    with caplog.at_level(logging.WARNING):
        assert inspect_photo(path, path.name).gps is None
    assert any(str(path) in r.getMessage() for r in caplog.records)


DJI_XMP_ATTRIBUTES = b"""<?xpacket begin='' id='W5M0MpCehiHzreSzNTczkc9d'?>
<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
<rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"
  drone-dji:AbsoluteAltitude="+512.35" drone-dji:RelativeAltitude="+60.10"
  drone-dji:GimbalRollDegree="+0.00" drone-dji:GimbalYawDegree="-92.30" drone-dji:GimbalPitchDegree="-89.90"
  drone-dji:FlightYawDegree="-90.10"/></rdf:RDF></x:xmpmeta><?xpacket end='w'?>"""

DJI_XMP_ELEMENTS = b"""<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF><rdf:Description>
<drone-dji:RelativeAltitude>+35.5</drone-dji:RelativeAltitude>
<drone-dji:GimbalPitchDegree>-45.0</drone-dji:GimbalPitchDegree>
</rdf:Description></rdf:RDF></x:xmpmeta>"""


def test_dji_xmp_read_from_attributes_and_elements():
    assert read_xmp_drone(DJI_XMP_ATTRIBUTES) == {"relative_alt": 60.1, "gimbal_roll": 0.0, "gimbal_yaw": -92.3,
                                                  "gimbal_pitch": -89.9}
    assert read_xmp_drone(DJI_XMP_ELEMENTS) == {"relative_alt": 35.5, "gimbal_pitch": -45.0}
    assert read_xmp_drone(b"<x:xmpmeta/>") == {} and read_xmp_drone(None) == {}


def test_drone_photo_gps_with_xmp(tmp_path):
    exif = _focal_exif(f35=24)
    add_gps(exif, GeoTag(47.3769, 8.5417, 468.2))
    tag = inspect_photo(_jpeg(tmp_path / "DJI_0001.jpg", exif, xmp=DJI_XMP_ATTRIBUTES), "DJI_0001.jpg").gps
    assert (tag.lat, tag.lon, tag.alt) == pytest.approx((47.3769, 8.5417, 468.2))
    assert (tag.relative_alt, tag.gimbal_yaw, tag.gimbal_pitch, tag.gimbal_roll) == (60.1, -92.3, -89.9, 0.0)


def test_gps_tag_without_pillow_exif_object():
    assert read_gps({}, None, "x.jpg") is None


@pytest.mark.datasets
def test_berlin_photos_gps_is_read(datasets):
    """The real phone photos: positions as their Mapillary metadata (ImageDescription) states them."""
    folder = datasets / "berlin" / "images"
    expected = {"01.jpg": (52.518918, 13.400295, 27.0), "02.jpg": (52.518925, 13.400387, 30.0),
                "03.jpg": (52.519047, 13.400445, 39.0)}
    for name, (lat, lon, alt) in expected.items():
        tag = inspect_photo(folder / name, name).gps
        assert (tag.lat, tag.lon, tag.alt) == pytest.approx((lat, lon, alt), abs=5e-6)  # 6-digit metadata
        assert tag.dop == 5.0 and tag.horizontal_error is None


@pytest.mark.datasets
def test_ingest_records_gps_per_photo(datasets, tmp_path):
    """ingest's images.json carries each photo's GPS object (null without one)."""
    import json
    import shutil

    import recon

    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("01.jpg", "02.jpg"):
        shutil.copy(datasets / "berlin" / "images" / name, photos / name)
    Image.new("RGB", (W, H), (10, 20, 30)).save(photos / "no_gps.jpg")
    ws = tmp_path / "ws"
    recon.run(None, images=str(photos), workspace=str(ws), until="ingest")
    (listing,) = ws.glob(".recon/cache/ingest/*/images.json")
    gps = {img["name"]: img["gps"] for img in json.loads(listing.read_text())["images"]}
    assert gps["no_gps.jpg"] is None
    assert gps["01.jpg"]["lat"] == pytest.approx(52.518917, abs=1e-6) and gps["01.jpg"]["alt"] == 27.0
    assert gps["02.jpg"]["dop"] == 5.0 and gps["02.jpg"]["gimbal_yaw"] is None
