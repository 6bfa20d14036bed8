"""undistort -> mvs -> fusion -> mesh -> texture through the pipeline: COLMAP layout, per-view resume,
a fused cloud and a mesh on the surface, textured exports that load."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import recon
from recon.mvs.colmap_io import read_depth_map, read_normal_map

REPO = Path(__file__).resolve().parents[2]
FULL = REPO / "pipelines" / "full.yaml"
# small and quick: the depth maps' quality is measured by tests/mvs and the benchmark
QUICK = ["sfm.deterministic=true", "undistort.max_image_size=240", "mvs.max_image_size=240", "mvs.pyramid_levels=2",
         "mvs.iterations=3", "mesh.depth=8", "mesh.target_faces=40000", "texture.max_faces=20000"]


def run_cli(ws: Path, scene: Path, *extra: str, flags: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "recon.cli", "run", str(FULL), "--images", str(scene / "images"),
           "--workspace", str(ws), "-o", "executor=serial", *flags]
    for o in [*QUICK, *extra]:
        cmd += ["-o", o]
    return subprocess.run(cmd, capture_output=True, text=True)


@pytest.fixture(scope="module")
def dense_workspace(sparse_workspace, small_scene, tmp_path_factory) -> Path:
    import shutil

    ws = tmp_path_factory.mktemp("dense") / "ws"
    shutil.copytree(sparse_workspace, ws, symlinks=True)
    done = run_cli(ws, small_scene)
    assert done.returncode == 0, done.stderr
    return ws


@pytest.fixture(scope="module")
def dense_figures(dense_workspace, small_scene) -> dict:
    """recon.api.evaluate of the dense workspace (poses, fused cloud, mesh), for the tests that read it."""
    return recon.api.evaluate(dense_workspace, small_scene)


def test_dense_layout_reads_like_colmap(dense_workspace):
    import pycolmap

    dense = dense_workspace / "dense"
    rec = pycolmap.Reconstruction(str(dense / "sparse"))
    assert {c.model.name for c in rec.cameras.values()} == {"PINHOLE"}
    names = sorted(img.name for img in rec.images.values())
    assert len(names) == 16 and all((dense / "images" / n).exists() for n in names)
    kept = []
    for n in names:
        depth = read_depth_map(dense / "stereo" / "depth_maps" / f"{n}.geometric.bin")
        normal = read_normal_map(dense / "stereo" / "normal_maps" / f"{n}.geometric.bin")
        assert depth.ndim == 2 and normal.shape == (*depth.shape, 3)
        kept.append(np.count_nonzero(depth) / depth.size)
    assert np.mean(kept) > 0.3


def test_fused_cloud_lies_on_the_ground_truth_surface(dense_figures):
    fused = dense_figures["fused"]
    assert fused["n_points"] > 5000
    assert fused["accuracy@0.005"] > 80  # at 240 px, a quick smoke check; quality is benchmarked elsewhere


def test_an_unchanged_second_run_runs_nothing(dense_workspace, small_scene):
    """The report's key once counted the dense outputs it shows twice (as upstream stages and as
    workspace state read while planning): absent when the first run was planned, so the next
    unchanged run made the report again."""
    again = recon.run(FULL, images=str(small_scene / "images"), workspace=str(dense_workspace), overrides=QUICK)
    assert again.ran == [] and "report" in again.cached


def test_killed_mvs_resumes_without_recomputing_finished_views(sparse_workspace, small_scene, tmp_path):
    import shutil

    ws = tmp_path / "ws"
    shutil.copytree(sparse_workspace, ws, symlinks=True)
    cmd = [sys.executable, "-m", "recon.cli", "run", str(FULL), "--images", str(small_scene / "images"),
           "--workspace", str(ws), "--until", "mvs", "-o", "executor=serial"]
    for o in [*QUICK, "mvs.max_image_size=160"]:  # (resuming is what is tested: smaller maps, sooner)
        cmd += ["-o", o]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    maps = lambda: sorted(ws.glob(".recon/cache/mvs/*.partial/stereo/depth_maps/*.photometric.bin"))  # noqa: E731
    deadline = time.monotonic() + 300
    while len(maps()) < 3:
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    finished = [p.name for p in maps()]
    assert 3 <= len(finished) < 16
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert f"mvs photometric: {len(finished)} of 16 already done, resuming" in done.stderr
    log = (ws / ".recon" / "recon.log").read_text()  # (the photometric maps are dropped once mvs completes)
    resumed = log[log.index("already done, resuming"):]
    for name in finished:
        assert f"{name.removesuffix('.photometric.bin')}: photometric depth" not in resumed, f"{name} was recomputed"
    assert resumed.count(": photometric depth") == 16 - len(finished)


def test_mesh_lies_on_the_ground_truth_surface(dense_figures):
    mesh = dense_figures["mesh"]
    assert mesh["accuracy@0.005"] > 70 and mesh["completeness@0.005"] > 50  # quick settings; see the benchmark


def test_textured_exports_load_with_their_texture(dense_workspace):
    import trimesh
    from PIL import Image

    glb = trimesh.load(dense_workspace / "textured.glb", force="mesh")
    assert len(glb.faces) > 1000
    image = glb.visual.material.baseColorTexture
    assert image is not None and min(image.size) >= 64
    assert np.asarray(image).std() > 10  # photo content, not a flat colour
    assert glb.visual.uv.min() >= -1e-6 and glb.visual.uv.max() <= 1 + 1e-6
    obj = trimesh.load(dense_workspace / "textured.obj", force="mesh")
    assert len(obj.faces) == len(glb.faces)
    assert "map_Kd textured.png" in (dense_workspace / "textured.mtl").read_text()
    assert np.asarray(obj.visual.material.image).shape == np.asarray(Image.open(dense_workspace / "textured.png")).shape
    colored = trimesh.load(dense_workspace / "mesh.ply")
    assert colored.visual.vertex_colors[:, :3].std() > 10


def test_the_mesh_cleanup_weighs_its_pieces_by_the_fused_points(dense_workspace):
    """The mesh stage hands the cleanup the fused points it meshed, so pieces with few of them can go
    (mesh.min_component_support; the rule itself: tests/surface/test_cleanup.py)."""
    log = (dense_workspace / ".recon" / "recon.log").read_text()
    assert "times the mesh's points per area dropped" in log


def test_the_mesh_stage_drops_what_no_view_sees_or_measures(dense_workspace):
    """mesh.drop_unseen runs in the pipeline, with the depth maps (the rule itself: tests/surface/test_unseen.py)."""
    import re

    log = (dense_workspace / ".recon" / "recon.log").read_text()
    assert re.search(r"mesh: \d+ faces dropped: no view sees them or their neighbours; \d+ more: 3 or more views "
                     r"see them and none measures them", log)


def test_the_mesh_is_built_from_a_cloud_fused_at_its_own_reprojection_error(dense_workspace):
    """fusion.merge_reproj_error 0.25 px gives dense/fused.ply; fusion.mesh_reproj_error 1 px the cloud that the
    mesh stage meshes, whose points each merge every pixel that agrees: fewer of them."""
    from recon.mvs.fused_ply import vertex_count

    delivered = vertex_count(dense_workspace / "dense" / "fused.ply")
    meshed = vertex_count(next(dense_workspace.glob(".recon/cache/fusion/*/meshing.ply")))
    assert delivered > 1.3 * meshed > 0
    log = (dense_workspace / ".recon" / "recon.log").read_text()
    assert f"faces from {meshed} points" in log and f"faces from {delivered} points" not in log


def test_each_cloud_merges_pixels_within_its_own_tolerances(dense_workspace, small_scene, tmp_path):
    """dense/fused.ply merges pixels within fusion.max_depth_error 0.03 and max_normal_error 60 degrees, the
    mesh's cloud within mesh_depth_error 0.01 and mesh_normal_error 10: with both clouds at one reprojection
    error and merge radius, the mesh still gets its own cloud; with every tolerance equal, there is no second
    cloud and the mesh takes dense/fused.ply."""
    import re
    import shutil

    from recon.mvs.fused_ply import vertex_count

    ws = tmp_path / "ws"
    shutil.copytree(dense_workspace, ws, symlinks=True)
    same_radius = ("fusion.max_reproj_error=0.5", "fusion.merge_reproj_error=0.5", "fusion.mesh_reproj_error=0.5")
    done = run_cli(ws, small_scene, *same_radius, flags=("--until", "fusion"))
    assert done.returncode == 0, done.stderr
    folder = _newest(ws / ".recon" / "cache" / "fusion").parent
    log = (ws / ".recon" / "recon.log").read_text()
    delivered = re.findall(r"fusion: (\d+) points within 0\.50 px \(merged within 0\.50\), 0\.03 of the depth and "
                           r"60 degrees into fused\.ply", log)
    meshed = re.findall(r"fusion: (\d+) points within 0\.50 px \(merged within 0\.50\), 0\.01 of the depth and "
                        r"10 degrees into meshing\.ply", log)
    assert delivered and meshed
    assert int(meshed[-1]) == vertex_count(folder / "meshing.ply") != vertex_count(folder / "fused.ply")
    done = run_cli(ws, small_scene, *same_radius, "fusion.mesh_depth_error=0.03", "fusion.mesh_normal_error=60",
                   flags=("--until", "fusion"))
    assert done.returncode == 0, done.stderr
    folder = _newest(ws / ".recon" / "cache" / "fusion").parent
    assert (folder / "fused.ply").exists() and not (folder / "meshing.ply").exists()


def test_delaunay_mesh_lies_on_the_surface_and_is_textured(dense_workspace, dense_figures, small_scene, tmp_path):
    """mesh.method: delaunay through the pipeline: the graph-cut surface of the fused points, textured."""
    import shutil

    import trimesh

    ws = tmp_path / "ws"
    shutil.copytree(dense_workspace, ws, symlinks=True)
    done = run_cli(ws, small_scene, "mesh.method=delaunay")
    assert done.returncode == 0, done.stderr
    manifest = json.loads(_newest(ws / ".recon" / "cache" / "mesh").read_text())
    assert manifest["config"]["method"] == "delaunay"
    poisson = dense_figures["mesh"]
    mesh = recon.api.evaluate(ws, small_scene)["mesh"]
    assert mesh["accuracy@0.005"] > 70 and mesh["completeness@0.005"] > 50  # as Poisson's, quick settings
    assert mesh["fscore@0.005"] > poisson["fscore@0.005"] - 10
    glb = trimesh.load(ws / "textured.glb", force="mesh")
    assert len(glb.faces) > 1000 and np.asarray(glb.visual.material.baseColorTexture).std() > 10


def _newest(cache: Path) -> Path:
    return max(cache.glob("*/manifest.json"), key=lambda p: p.stat().st_mtime_ns)


def test_textured_glb_is_the_right_way_up(dense_workspace):
    """The photos' up is -Y in COLMAP's mapper frame (its first camera's: y points down the image);
    glTF viewers take +Y as up. The scene's ground (a 6 x 6 square, objects standing on it) is then
    the GLB's thinnest direction, along Y, and lies at the bottom: the lowest vertices are on one flat
    level (the ground), the highest spread over the objects' tops. Upside down, it is the reverse."""
    import trimesh

    glb = trimesh.load(dense_workspace / "textured.glb", force="mesh")
    vertices = np.asarray(glb.vertices)
    thinnest = np.linalg.svd(vertices - vertices.mean(0), full_matrices=False)[2][2]
    assert abs(thinnest[1]) > 0.95, thinnest
    p1, p5, p95, p99 = np.percentile(vertices[:, 1], [1, 5, 95, 99])
    assert p5 - p1 < (p99 - p95) / 5, (p1, p5, p95, p99)
    gltf = json.loads(trimesh.util.decode_text(_glb_json(dense_workspace / "textured.glb")))
    assert gltf["materials"][0].get("doubleSided") is True  # an open surface: seen from both sides


def _glb_json(path: Path) -> bytes:
    """The JSON chunk of a GLB file (header 12 bytes, then chunk length, type 'JSON', data)."""
    data = path.read_bytes()
    length = int.from_bytes(data[12:16], "little")
    assert data[16:20] == b"JSON"
    return data[20:20 + length]


def test_mesh_is_reproducible(dense_workspace, small_scene, tmp_path):
    """The same config and seed give the same mesh (issue 7): re-running the mesh stage rewrites it identically."""
    import shutil

    ws = tmp_path / "ws"
    shutil.copytree(dense_workspace, ws, symlinks=True)
    first = next(ws.glob(".recon/cache/mesh/*/mesh.ply")).read_bytes()
    done = run_cli(ws, small_scene, flags=("--force", "mesh", "--until", "mesh"))
    assert done.returncode == 0, done.stderr
    second = next(ws.glob(".recon/cache/mesh/*/mesh.ply")).read_bytes()
    assert first == second  # mesh.deterministic: single-threaded Poisson (multi-threaded, 1 % of the
    # vertices moved by up to 5e-4 of the extent between two runs, as its densities changed the trimming)


def test_fusion_is_reproducible(dense_workspace, small_scene, tmp_path):
    """The same depth maps give the same fused cloud, byte for byte (issue 13). COLMAP's fusion, multi-threaded,
    merged pixels in the order its threads reached them: three runs of this scene gave three point counts."""
    import shutil

    ws = tmp_path / "ws"
    shutil.copytree(dense_workspace, ws, symlinks=True)
    clouds = [next(ws.glob(".recon/cache/fusion/*/fused.ply")).read_bytes()]
    for _ in range(2):
        done = run_cli(ws, small_scene, flags=("--force", "fusion", "--until", "fusion"))
        assert done.returncode == 0, done.stderr
        clouds.append(next(ws.glob(".recon/cache/fusion/*/fused.ply")).read_bytes())
    assert clouds[0] == clouds[1] == clouds[2]


def test_two_agreeing_views_make_a_more_complete_cloud(dense_workspace, small_scene, tmp_path):
    """fusion.min_num_pixels 2 (the default) keeps the surface only two views see, which 3 leaves out."""
    import shutil

    import trimesh

    from recon.eval.surface import surface_metrics
    from recon.synth import load_scene

    ws = tmp_path / "ws"
    shutil.copytree(dense_workspace, ws, symlinks=True)
    done = run_cli(ws, small_scene, "fusion.min_num_pixels=3", flags=("--until", "fusion"))
    assert done.returncode == 0, done.stderr
    clouds = {json.loads((p.parent / "manifest.json").read_text())["config"]["min_num_pixels"]: p
              for p in (ws / ".recon" / "cache" / "fusion").glob("*/fused.ply")}
    sim = recon.api.model_to_ground_truth(ws, small_scene)
    info = load_scene(small_scene)
    figures = {k: surface_metrics(sim.apply(np.asarray(trimesh.load(p).vertices)), info) for k, p in clouds.items()}
    assert figures[2]["n_points"] > figures[3]["n_points"]
    assert figures[2]["completeness@0.005"] > figures[3]["completeness@0.005"] + 0.8  # 98.4 against 97.2
    assert figures[2]["accuracy@0.005"] > figures[3]["accuracy@0.005"] - 1  # 99.8 against 99.9


def test_mesh_faces_the_views_see_through_are_dropped(dense_workspace, dense_figures, small_scene, tmp_path):
    """mesh.free_space (on by default): faces whose centre more views see through than agree with go, where
    the mesh lies behind them (recon.surface.seen_through), from the same surface; what stays is at least as
    accurate as the surface with them."""
    import shutil

    ws = tmp_path / "ws"
    shutil.copytree(dense_workspace, ws, symlinks=True)
    done = run_cli(ws, small_scene, "mesh.free_space=false")
    assert done.returncode == 0, done.stderr
    runs = {m["config"]["free_space"]: m["summary"] for m in
            (json.loads(p.read_text()) for p in (ws / ".recon" / "cache" / "mesh").glob("*/manifest.json"))}
    dropped = runs[True]["free_space_faces_dropped"]
    assert dropped > 0 and runs[False]["free_space_faces_dropped"] == 0
    # the backdrop test runs next, on what is left, and may decide a face behind a dropped one otherwise
    before_backdrop = {k: r["faces"] + r["finer_than_the_photos_faces_dropped"] + r["backdrop_faces_dropped"]
                       for k, r in runs.items()}
    assert before_backdrop[True] == before_backdrop[False] - dropped
    accuracy = {"with": dense_figures["mesh"]["accuracy@0.005"],
                "without": recon.api.evaluate(ws, small_scene)["mesh"]["accuracy@0.005"]}
    assert accuracy["with"] >= accuracy["without"] - 0.1, accuracy
