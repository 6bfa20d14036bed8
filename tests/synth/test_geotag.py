"""GPS tags written into synthetic photos (recon.synth.geotags) read back, through ingest's reader, as written."""

from __future__ import annotations

import numpy as np
from PIL import Image

from recon.eval.groundtruth import Camera
from recon.geometry.gps import enu_from_wgs84, read_gps
from recon.synth.geotags import geotag_photos

ORIGIN = (-33.8688, 151.2093, 58.0)  # southern and eastern: the references must come out right


def test_geotagged_photos_read_back_their_positions_and_keep_their_pixels(tmp_path):
    rng = np.random.default_rng(0)
    cameras = {}
    for k in range(3):
        name = f"view_{k:03d}.jpg"
        Image.fromarray(rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)).save(
            tmp_path / name, quality=90, exif=Image.Exif())
        centre = rng.uniform(-300, 300, 3)
        cameras[name] = Camera(np.eye(3), np.eye(3), -centre, 32, 24)
    before = {name: np.asarray(Image.open(tmp_path / name)) for name in cameras}
    tagged = geotag_photos(tmp_path, {n: c.center for n, c in cameras.items()}, 2.0, 1, ORIGIN)
    for name, cam in cameras.items():
        with Image.open(tmp_path / name) as img:
            tag = read_gps(img.getexif(), None, name)
            assert np.array_equal(np.asarray(img), before[name])
        assert tag.horizontal_error == 2.0
        enu, written = enu_from_wgs84(np.array([[tag.lat, tag.lon, tag.alt],
                                                [tagged[name].lat, tagged[name].lon, tagged[name].alt]]), ORIGIN)
        assert np.abs(enu - written).max() < 0.01  # 1e-4 arc seconds, 1 mm altitude
        assert 0 < np.linalg.norm(written - cam.center) < 5 * 2.0  # the centre, plus noise of sigma 2 m
