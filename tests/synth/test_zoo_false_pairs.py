"""Zoo scenes must not fool two-view geometry by construction: photos from opposite sides of an orbit
see no surface alike, so matches between them that the pair's verification keeps, and the true
geometry does not explain, are an artefact of the scene. A ground texture tiled a few times over
matched every pair of opposite photos of plain_boxes (220 verified matches between views 0 and 12; 41 %
of all its verified matches were false) and its cameras came out 50 degrees wrong."""

import sqlite3

import numpy as np
import pytest

import recon
from recon.synth.zoo import render_zoo

#: orbit scenes whose two views (the layout's ends) face each other across the scene. Not courtyard: its
#: walls are a photo of bricks, periodic as real brick is (53 false matches; its mapper copes, AUC@5 98)
OPPOSITE = ("plain_boxes", "turntable_black", "exposure_wb", "noisy_phone", "fence_poles", "clutter")


def _true_fundamental(a, b) -> np.ndarray:
    R = b.R @ a.R.T
    t = b.t - R @ a.t
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(b.K).T @ tx @ R @ np.linalg.inv(a.K)


def false_matches(database, cameras) -> int:
    """Verified matches of the database's pairs lying over 3 px off the true epipolar lines."""
    con = sqlite3.connect(f"file:{database}?mode=ro&immutable=1", uri=True)
    names = dict(con.execute("SELECT image_id, name FROM images"))
    width = {i: w for i, w in con.execute("SELECT image_id, width FROM images JOIN cameras USING (camera_id)")}
    points = {i: np.frombuffer(b, np.float32).reshape(r, c)[:, :2]
              for i, r, c, b in con.execute("SELECT image_id, rows, cols, data FROM keypoints")}
    false = 0
    for pair, rows, blob in con.execute("SELECT pair_id, rows, data FROM two_view_geometries WHERE rows > 0"):
        j = pair % 2147483647
        i = (pair - j) // 2147483647
        m = np.frombuffer(blob, np.uint32).reshape(rows, 2)
        a, b = cameras[names[i]], cameras[names[j]]
        x1 = points[i][m[:, 0]] * (a.width / width[i])
        x2 = points[j][m[:, 1]] * (b.width / width[j])
        lines = np.column_stack([x1, np.ones(rows)]) @ _true_fundamental(a, b).T
        error = np.abs(np.sum(np.column_stack([x2, np.ones(rows)]) * lines, 1)) / np.linalg.norm(lines[:, :2], axis=1)
        false += int(np.count_nonzero(error > 3.0))
    con.close()
    return false


@pytest.mark.slow
@pytest.mark.parametrize("name", OPPOSITE)
def test_opposite_photos_share_no_false_geometry(tmp_path, name):
    scene = render_zoo(name, tmp_path / "scene", views=2, holdout=0, width=320, height=240)
    recon.run("pipelines/sparse.yaml", images=str(scene.images_dir), workspace=str(tmp_path / "ws"),
              until="matching", overrides=["executor=serial"])
    assert false_matches(tmp_path / "ws" / "database.db", scene.cameras()) < 15  # sfm.min_num_matches
