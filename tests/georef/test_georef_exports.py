"""Scale bars and GCPs through the pipeline (sfm options), and issue 16's "Done when" 2: with a model
placed in metres, every export (COLMAP model binary and text, points.ply, transforms.json, the dense
workspace's model, fused.ply, mesh.ply, textured.glb, textured.obj) is in the one frame: the true
cameras and the true surface, carried into that frame, coincide with each."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pycolmap
import pytest
import trimesh
from control_scene import METRES_PER_UNIT, ORIGIN, marked_points, true_enu, write_gcp_list

import recon
from recon.config import ConfigError
from recon.geometry.gps import enu_from_wgs84, wgs84_from_enu
from recon.geometry.transforms import umeyama
from recon.stage import StageError
from recon.surface.export import Z_UP_TO_GLTF, read_glb
from recon.synth import load_scene

REPO = Path(__file__).resolve().parents[2]
SPARSE_TEST = REPO / "tests" / "sparse_test.yaml"
FULL = REPO / "pipelines" / "full.yaml"
QUICK = {"undistort": {"max_image_size": 240}, "mvs": {"max_image_size": 240, "pyramid_levels": 2, "iterations": 3},
         "mesh": {"depth": 8, "target_faces": 40000}, "texture": {"max_faces": 20000}}


def _bar_config(a, b) -> dict:
    return {"length": float(METRES_PER_UNIT * np.linalg.norm(a.world - b.world)),
            "a": [{"photo": n, "x": float(x), "y": float(y)} for n, (x, y) in a.pixels.items()],
            "b": [{"photo": n, "x": float(x), "y": float(y)} for n, (x, y) in b.pixels.items()]}


def test_scale_bar_config_puts_the_workspace_in_metres(small_scene, copy_workspace):
    a, b = marked_points(small_scene, 2, noise_px=0.3, seed=1, spread=1.5)
    result = recon.run(SPARSE_TEST, images=str(small_scene / "images"), workspace=str(copy_workspace),
                       sfm={"scale_bars": [_bar_config(a, b)]})
    assert "sfm" in result.ran and "features" in result.cached  # only sfm and what follows re-ran
    georef = json.loads((copy_workspace / "georeference.json").read_text())
    assert georef["scale_source"] == "scale bar" and len(georef["scale_bars"]) == 1
    model = pycolmap.Reconstruction(str(copy_workspace / "sparse" / "0"))
    found = {img.name: img.projection_center() for img in model.images.values()}
    true = {n: METRES_PER_UNIT * c.center for n, c in load_scene(small_scene).cameras().items()}
    scale = umeyama(np.array([found[n] for n in sorted(found)]), np.array([true[n] for n in sorted(found)])).s
    assert abs(scale - 1) < 0.01
    cloud = trimesh.load(copy_workspace / "points.ply")  # the export follows
    xyz = np.array([p.xyz for p in model.points3D.values()])
    assert np.allclose(np.sort(cloud.vertices, axis=0), np.sort(xyz, axis=0), atol=1e-4)


def test_bad_control_options_are_one_line_errors(small_scene, copy_workspace, tmp_path):
    images, ws = str(small_scene / "images"), str(copy_workspace)
    with pytest.raises(StageError, match=r"^sfm\.gcp_file: .*nowhere\.txt is not a file"):
        recon.run(SPARSE_TEST, images=images, workspace=ws, sfm={"gcp_file": str(tmp_path / "nowhere.txt")})
    with pytest.raises(ConfigError, match=r"sfm\.scale_bars\[0\]\.lenght: unknown key; did you mean 'length'"):
        recon.run(SPARSE_TEST, images=images, workspace=ws, sfm={"scale_bars": [{"lenght": 1.0}]})
    bad = tmp_path / "gcp_list.txt"
    bad.write_text("EPSG:32632\n464310 5248101 412 10 10\n")
    with pytest.raises(StageError, match=r"^sfm\.gcp_file: .*gcp_list\.txt:2: expected 'geo_x geo_y"):
        recon.run(SPARSE_TEST, images=images, workspace=ws, sfm={"gcp_file": str(bad)})
    too_few = tmp_path / "two.txt"
    write_gcp_list(too_few, marked_points(small_scene, 2, seed=8, spread=1.0))
    with pytest.raises(StageError, match=r"^sfm\.gcp_file: the GCPs cannot place the model: 2 control point\(s\): "
                                         r"at least 3 are needed without GPS"):
        recon.run(SPARSE_TEST, images=images, workspace=ws, sfm={"gcp_file": str(too_few)})


def _to_result_frame(enu_at_origin: np.ndarray, georef: dict) -> np.ndarray:
    origin = tuple(georef["origin"][k] for k in ("lat", "lon", "alt"))
    return enu_from_wgs84(wgs84_from_enu(enu_at_origin, ORIGIN), origin)


def _distance_to(surface: trimesh.Trimesh, points: np.ndarray, samples: int = 3000) -> np.ndarray:
    """Distances of (a sample of) ``points`` to the triangles of ``surface`` (open3d's ray-casting scene)."""
    from recon._open3d import open3d

    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(surface.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(surface.faces, np.uint32)))
    rng = np.random.default_rng(0)
    chosen = points[rng.choice(len(points), min(samples, len(points)), replace=False)]
    return scene.compute_distance(o3d.core.Tensor(np.asarray(chosen, np.float32))).numpy()


@pytest.mark.slow
def test_every_export_is_in_the_gcp_frame(small_scene, copy_workspace, tmp_path):
    """The model placed on GCPs (UTM 32N), then the full pipeline: each export shows the true camera
    centres and the true surface where they are in ENU metres."""
    points = marked_points(small_scene, 6, noise_px=0.3, seed=3, spread=0.8)
    gcp_file = tmp_path / "gcp_list.txt"
    write_gcp_list(gcp_file, points)
    ws = copy_workspace
    recon.run(FULL, images=str(small_scene / "images"), workspace=str(ws), executor="serial",
              sfm={"deterministic": True, "gcp_file": str(gcp_file)}, **QUICK)
    georef = json.loads((ws / "georeference.json").read_text())
    assert georef["scale_source"] == "GCP" and georef["gcp"]["outliers"] == []
    scene, truth = load_scene(small_scene), true_enu()
    true_centres = {n: _to_result_frame(truth.apply(c.center), georef)[0] for n, c in scene.cameras().items()}
    gt = trimesh.load(scene.mesh_path, force="mesh")
    surface = trimesh.Trimesh(_to_result_frame(truth.apply(gt.vertices), georef), gt.faces, process=False)

    # cameras: the COLMAP model (binary, text, the dense workspace's) and transforms.json
    for folder in ("sparse/0", "sparse_text", "dense/sparse"):
        model = pycolmap.Reconstruction(str(ws / folder))
        error = [np.linalg.norm(img.projection_center() - true_centres[img.name]) for img in model.images.values()]
        assert np.median(error) < 0.15, (folder, np.median(error))
    frames = json.loads((ws / "transforms.json").read_text())["frames"]
    error = [np.linalg.norm(np.asarray(f["transform_matrix"])[:3, 3] - true_centres[Path(f["file_path"]).name])
             for f in frames]
    assert len(frames) == 16 and np.median(error) < 0.15

    # the surface: sparse points, fused cloud, meshes; the GLB in glTF's Y-up axes
    clouds = {
        "points.ply": np.asarray(trimesh.load(ws / "points.ply").vertices),
        "dense/fused.ply": np.asarray(trimesh.load(ws / "dense" / "fused.ply").vertices),
        "mesh.ply": np.asarray(trimesh.load(ws / "mesh.ply", force="mesh").vertices),
        "textured.glb": np.asarray(read_glb(ws / "textured.glb").vertices),
        "textured.obj": np.asarray(trimesh.load(ws / "textured.obj", force="mesh").vertices),
    }
    figures = {}
    for name, xyz in clouds.items():
        figures[name] = float(np.median(_distance_to(surface, xyz)))
    print("median distance to the true surface (m): " + ", ".join(f"{k} {v:.3f}" for k, v in figures.items()))
    assert all(v < 0.15 for v in figures.values()), figures
    raw = trimesh.load(ws / "textured.glb", force="mesh").vertices  # as a glTF viewer sees it: Y up
    assert np.allclose(raw, trimesh.transform_points(clouds["textured.glb"], Z_UP_TO_GLTF), atol=1e-4)
    glb = (ws / "textured.glb").read_bytes()  # the GLB and the OBJ name the frame and its origin
    recorded = json.loads(glb[20:20 + int.from_bytes(glb[12:16], "little")])["asset"]["extras"]["georeference"]
    obj = json.loads((ws / "textured.obj").read_text().splitlines()[0].removeprefix("# georeference: "))
    assert recorded["origin_wgs84"] == obj["origin_wgs84"] == georef["origin"] and recorded["crs"] == georef["crs"]
