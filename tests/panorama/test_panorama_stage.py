"""The panorama stage through the pipeline: outputs written and published, unstitched photos
reported, hopeless inputs refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pano_eval as pe
import pytest
from PIL import Image

import recon
from recon.panorama import PanoramaModel
from recon.stage import StageError
from recon.synth import panorama as sp
from recon.synth.textures import fit, photo

PIPELINE = Path(__file__).resolve().parents[2] / "pipelines" / "panorama.yaml"


def test_stage_writes_publishes_and_reports_unstitched_photos(tmp_path):
    views = sp.render_views(views=10, width=320, height=240, hfov_deg=55.0, seed=3)
    images = sp.write_views(tmp_path / "set", views)
    Image.fromarray(fit(photo("rocket"), 320, 240)).save(images / "stray.png")  # from elsewhere
    ws = tmp_path / "ws"
    result = recon.run(PIPELINE, images=str(images), workspace=str(ws))
    assert result.ran == ["ingest", "panorama"]
    assert result.summaries["panorama"]["stitched"] == 10 and result.summaries["panorama"]["dropped"] == 1
    for name in ("panorama.jpg", "panorama.json"):
        assert (ws / name).is_symlink() and (ws / name).exists()
    info = json.loads((ws / "panorama.json").read_text())
    pano = np.asarray(Image.open(ws / "panorama.jpg"))
    assert pano.shape == (info["height"], info["width"], 3)
    assert info["full_circle"] and info["width"] == round(2 * np.pi * info["scale"])
    assert abs(info["focal"] / views.K[0, 0] - 1) < 0.01
    photos = {p["name"]: p for p in info["photos"]}
    assert not photos["stray.png"]["stitched"] and "no overlap" in photos["stray.png"]["reason"]
    assert all(photos[n]["stitched"] and photos[n]["inliers"] > 100 for n in views.names)
    assert {frozenset((p["a"], p["b"])) for p in info["pairs"]} >= {frozenset((views.names[0], views.names[-1]))}
    # the json's model maps known directions onto the markers in the written JPEG
    model = PanoramaModel.from_dict(info)
    first = photos[views.names[0]]["camera"]
    px = model.to_pixel(sp.direction(sp.marker_azimuths()) @ views.rotations[0].T, camera=first)
    found = np.array([pe.marker_centroid(pano, x, y, 8) for x, y in px])
    assert np.abs(found - px).max() < 1.0
    assert set(info["timings_s"]) >= {"features", "matching", "bundle_adjustment", "seams", "blend", "wrap"}
    again = recon.run(PIPELINE, images=str(images), workspace=str(ws))  # cached
    assert again.cached == ["ingest", "panorama"]


@pytest.mark.parametrize("names", [("chelsea", "coins", "brick"), ("chelsea",)])
def test_hopeless_input_is_a_one_line_stage_error(tmp_path, names):
    """Unrelated photos (or a single one) cannot make a panorama: one line that says why."""
    folder = tmp_path / "photos"
    folder.mkdir()
    for name in names:
        Image.fromarray(fit(photo(name), 320, 240)).save(folder / f"{name}.png")
    with pytest.raises(StageError) as err:
        recon.run({"stages": ["ingest", "panorama"]}, images=str(folder), workspace=str(tmp_path / "ws"))
    message = str(err.value)
    assert "\n" not in message
    assert ("overlap" in message) if len(names) > 1 else ("at least 2" in message)
