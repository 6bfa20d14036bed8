"""Fisheye and 360-degree photos told apart by their metadata: ``ingest.camera_model: auto`` picks
their models, a pinhole model on them is warned about, and a pinhole fit to a fisheye too."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from PIL import ExifTags, Image

import recon
from recon.files import read_json
from recon.sparse import lens
from recon.sparse.photos import inspect_photo
from recon.synth.wide import gpano_xmp

LENS_MODEL, FOCAL_35MM = ExifTags.Base.LensModel, ExifTags.Base.FocalLengthIn35mmFilm


def _photo(path: Path, size: tuple[int, int], lens_model: str | None = None, f35: int | None = None,
           xmp: bytes | None = None) -> Path:
    rng = np.random.default_rng(list(path.as_posix().encode()))
    img = Image.fromarray(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    exif = Image.Exif()
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    if lens_model is not None:
        sub[LENS_MODEL] = lens_model
    if f35 is not None:
        sub[FOCAL_35MM] = f35
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path, quality=90, exif=exif, **({"xmp": xmp} if xmp else {}))
    return path


@pytest.mark.parametrize(("lens_model", "f35", "xmp", "size", "expected"), [
    ("Samyang 8mm f/3.5 UMC Fish-eye CS II", None, False, (300, 200), "fisheye"),
    ("EF8-15mm f/4L FISHEYE USM", 15, False, (300, 200), "fisheye"),
    (None, 10, False, (300, 200), "fisheye"),  # 35 mm equivalent below 14 mm
    (None, 14, False, (300, 200), "perspective"),
    ("EF24-105mm f/4L IS USM", 24, False, (300, 200), "perspective"),
    (None, None, True, (400, 200), "equirectangular"),  # GPano on a 2:1 photo
    (None, None, True, (300, 200), "perspective"),  # GPano tags on a crop that is not 2:1
    (None, None, False, (400, 200), "perspective"),  # 2:1 alone says nothing
])
def test_written_exif_and_xmp_give_the_projection(tmp_path, lens_model, f35, xmp, size, expected):
    path = _photo(tmp_path / "a.jpg", size, lens_model, f35, gpano_xmp(*size) if xmp else None)
    assert inspect_photo(path, "a.jpg").projection == expected


def test_gpano_as_an_element_and_in_a_png(tmp_path):
    packet = (b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF><rdf:Description>'
              b'<GPano:ProjectionType>equirectangular</GPano:ProjectionType></rdf:Description></rdf:RDF></x:xmpmeta>')
    assert lens.projection({}, packet, 400, 200) == "equirectangular"
    assert lens.projection({}, packet.decode(), 400, 200) == "equirectangular"
    from PIL import PngImagePlugin

    info = PngImagePlugin.PngInfo()
    info.add_itxt("XML:com.adobe.xmp", gpano_xmp(400, 200).decode())
    Image.new("RGB", (400, 200)).save(tmp_path / "p.png", pnginfo=info)
    assert inspect_photo(tmp_path / "p.png", "p.png").projection == "equirectangular"


def _ingest(images: Path, ws: Path, model: str) -> dict:
    result = recon.run({"until": "ingest", "ingest": {"camera_model": model}}, images=str(images), workspace=str(ws))
    assert "ingest" in result.ran
    state = read_json(ws / ".recon" / "state.json")["ingest"][:16]
    return read_json(ws / ".recon" / "cache" / "ingest" / state / "images.json")


@pytest.fixture
def mixed(tmp_path) -> Path:
    """Three folders (so three cameras): fisheye by lens model, 360 panoramas, ordinary photos."""
    src = tmp_path / "photos"
    for i in range(2):
        _photo(src / "fisheye" / f"f{i}.jpg", (320, 240), "Fisheye 7.5mm")
        _photo(src / "pano" / f"p{i}.jpg", (400, 200), xmp=gpano_xmp(400, 200))
        _photo(src / "plain" / f"n{i}.jpg", (320, 240), f35=28)
    return src


def test_auto_picks_the_model_per_camera(tmp_path, mixed):
    listing = _ingest(mixed, tmp_path / "ws", "auto")
    by_folder = {img["name"].split("/")[0]: listing["cameras"][img["camera"] - 1] for img in listing["images"]}
    assert by_folder["fisheye"]["model"] == "OPENCV_FISHEYE"
    assert by_folder["fisheye"]["prior_focal"] is False  # no focal in EXIF: features estimates it
    assert by_folder["pano"]["model"] == "EQUIRECTANGULAR" and by_folder["pano"]["prior_focal"] is False
    assert by_folder["plain"]["model"] == "SIMPLE_RADIAL" and by_folder["plain"]["prior_focal"] is True
    assert {img["name"].split("/")[0]: img["projection"] for img in listing["images"]} == {
        "fisheye": "fisheye", "pano": "equirectangular", "plain": "perspective"}


def test_a_pinhole_model_on_fisheye_and_360_photos_is_warned_about(tmp_path, mixed, caplog):
    with caplog.at_level(logging.WARNING):
        listing = _ingest(mixed, tmp_path / "ws", "SIMPLE_RADIAL")
    assert {c["model"] for c in listing["cameras"]} == {"SIMPLE_RADIAL"}  # as asked
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("fisheye" in w and "ingest.camera_model" in w and "OPENCV_FISHEYE" in w for w in warned), warned
    assert any("360-degree" in w and "EQUIRECTANGULAR" in w for w in warned), warned
    assert not any("plain/" in w for w in warned if "ingest.camera_model" in w)
    assert any("fisheye/f0.jpg" in w for w in warned), warned  # the warning says which photos


def test_model_warning_rules():
    assert lens.model_warning("OPENCV_FISHEYE", ["fisheye"] * 3, [(640, 480)] * 3) is None
    assert lens.model_warning("SIMPLE_RADIAL", ["perspective"] * 3, [(640, 480)] * 3) is None
    assert "EQUIRECTANGULAR" in lens.model_warning("SIMPLE_RADIAL", ["perspective"] * 2, [(800, 400)] * 2)
    assert lens.model_warning("EQUIRECTANGULAR", ["perspective"] * 2, [(800, 400)] * 2) is None
    assert lens.auto_model(["fisheye", "fisheye", "perspective"]) == "OPENCV_FISHEYE"


def test_a_pinhole_fit_to_a_fisheye_is_recognised():
    # what SIMPLE_RADIAL converges to on the synthetic 176-degree fisheye orbit (640 x 480)
    folded = pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=480, params=[194.8, 319.7, 248.8, -0.0724])
    why = lens.pinhole_fit_warning(folded)
    assert why is not None and "OPENCV_FISHEYE" in why and "folds back" in why
    wide = pycolmap.Camera(model="SIMPLE_PINHOLE", width=640, height=480, params=[150.0, 320, 240])
    assert "across the diagonal" in lens.pinhole_fit_warning(wide)  # 2 atan(400 / 150) = 139 degrees
    for params in ([576.0, 320, 240, 0.0], [400.0, 320, 240, -0.05], [300.0, 320, 240, 0.02]):  # 42 to 107 degrees
        camera = pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=480, params=params)
        assert lens.pinhole_fit_warning(camera) is None, params
    fisheye = pycolmap.Camera(model="OPENCV_FISHEYE", width=640, height=480, params=[130, 130, 320, 240, 0, 0, 0, 0])
    assert lens.pinhole_fit_warning(fisheye) is None
