"""The zoo's GPS tags (recon.synth.geotags): what the photos' EXIF says, read back by ingest's reader,
is what gt/geotags.json records, and lies within the stated noise of the true camera centres."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image

from recon.geometry.gps import enu_from_wgs84, read_gps
from recon.synth.geotags import ORIGIN
from recon.synth.zoo import render_zoo, zoo_setup


def test_walkaround_photos_carry_their_noisy_gps(tmp_path):
    info = render_zoo("walkaround", tmp_path / "scene", views=6, width=160, height=120, holdout=1)
    recorded = json.loads((info.root / "gt" / "geotags.json").read_text())
    assert sorted(recorded) == sorted(info.image_names)  # regular views only, not the hold-out one
    sigma = zoo_setup("walkaround").gps_sigma
    offsets = []
    for name, cam in info.cameras().items():
        with Image.open(info.images_dir / name) as img:
            tag = read_gps(img.getexif(), None, name)
        want = recorded[name]
        assert abs(tag.lat - want["lat"]) < 1e-7 and abs(tag.lon - want["lon"]) < 1e-7  # DMS to 1e-4 s
        assert abs(tag.alt - want["alt"]) < 1e-3 and tag.horizontal_error == sigma
        offsets.append(enu_from_wgs84(np.array([tag.lat, tag.lon, tag.alt]), ORIGIN)[0] - cam.center)
    offsets = np.array(offsets)
    assert np.all(np.abs(offsets) < 5 * sigma) and np.abs(offsets).max() > 0.1  # noisy, within the noise
