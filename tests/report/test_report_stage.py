"""The report stage reads dense outputs only from stages built on the workspace's current sparse model."""

from __future__ import annotations

import numpy as np

from recon.files import write_json
from recon.geometry.transforms import up_direction
from recon.mvs.colmap_io import write_map
from recon.report.gather import read_model
from recon.report.viewer import frustum_segments
from recon.stages.report import _current_optional
from recon.workspace import Workspace


def _fake_output(ws: Workspace, stage: str, key: str, upstream: dict) -> None:
    out = ws.output_dir(stage, key)
    out.mkdir(parents=True)
    write_json(out / "manifest.json", {"stage": stage, "key": key, "upstream": upstream})
    ws.set_state(stage, key)


def test_dense_maps_of_an_older_sparse_model_are_left_out(copy_workspace):
    ws = Workspace(copy_workspace)
    state = ws.state()
    _fake_output(ws, "undistort", "u" * 64, {"ingest": state["ingest"], "sfm": "an older sfm key"})
    _fake_output(ws, "mvs", "m" * 64, {"undistort": "u" * 64})
    write_map(ws.output_dir("mvs", "m" * 64) / "stereo" / "depth_maps" / "a.jpg.geometric.bin", np.ones((4, 5)))
    assert _current_optional(ws) == []
    # the same dense stages built on the current model are shown
    write_json(ws.output_dir("undistort", "u" * 64) / "manifest.json",
               {"stage": "undistort", "upstream": {"ingest": state["ingest"], "sfm": state["sfm"]}})
    found = _current_optional(ws)
    assert [(stage, attr, path.name) for stage, _, (attr, path) in found] == [("mvs", "stereo", "stereo")]


def test_frustums_reproject_to_the_image_corners(sparse_workspace):
    model, _ = read_model(sparse_workspace / "sparse" / "0")
    segments = frustum_segments(model, depth=0.5).reshape(len(model.names), 16, 3)
    for R, C, (fx, fy, cx, cy, w, h), seg in zip(model.rotations, model.centers, model.intrinsics, segments):
        assert np.allclose(seg[0], C)  # the apex is the camera centre
        corners = seg[1::4]  # the far end of each apex-to-corner segment
        x = (corners - C) @ R.T  # camera frame
        assert np.allclose(x[:, 2], 0.5)  # at the asked depth
        uv = x[:, :2] / x[:, 2:] * [fx, fy] + [cx, cy]
        assert np.allclose(uv, [[0, 0], [w, 0], [w, h], [0, h]], atol=1e-6)


def test_up_is_against_the_cameras_image_down_axis():
    tilt = np.deg2rad(10)
    # cameras looking horizontally (world z up), slightly rolled: image-down is about -z
    R0 = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    roll = np.array([[np.cos(tilt), -np.sin(tilt), 0], [np.sin(tilt), np.cos(tilt), 0], [0, 0, 1]])
    up = up_direction(np.stack([R0, roll @ R0]), np.zeros((2, 3)))
    assert up @ [0, 0, 1] > 0.98
