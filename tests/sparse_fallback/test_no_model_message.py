"""The "no model" message says what actually failed (issue 16): two photos that match strongly, with
a wide baseline, made the mapper start, yet sfm used to say that no strong pair gave a first two-view
model. It now measures each strong pair's start as COLMAP's mapper does and names the real cause."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import recon
from recon.stage import StageError

SPARSE_TEST = Path(__file__).resolve().parents[1] / "sparse_test.yaml"


def test_two_photos_that_can_start_a_model_are_told_the_model_size(small_scene, tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("view_000.jpg", "view_001.jpg"):  # neighbours on the orbit, 22.5 degrees apart
        shutil.copy(small_scene / "images" / name, photos / name)
    with pytest.raises(StageError) as error:
        recon.run(SPARSE_TEST, images=str(photos), workspace=str(tmp_path / "ws"), until="sfm")
    message = str(error.value)
    assert "Only 2 photos: the mapper can start from view_000.jpg and view_001.jpg" in message
    assert "a model needs sfm.min_model_size (3) photos" in message
    assert "none of them gave a first two-view model" not in message  # the claim that was false here
