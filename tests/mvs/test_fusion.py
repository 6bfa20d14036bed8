"""Fusion of depth maps (recon.mvs.fusion): at COLMAP's pixel convention and merge radius it is COLMAP's
fusion; at recon's, exact maps fuse onto the true surface; a smaller merge radius gives a denser cloud of
the same accuracy; the cloud and its visibility are written in COLMAP's formats."""

import shutil

import numpy as np
import pycolmap
import pytest
from scipy.spatial import cKDTree

from recon._open3d import open3d
from recon.mvs import fusion
from recon.mvs.colmap_io import write_map
from recon.mvs.fused_ply import vertex_count, write_cloud, write_visibility
from recon.mvs.fusion import BYTES_PER_PIXEL, Tolerances, fuse, read_views
from recon.mvs.stereo import map_path
from recon.synth import load_scene

COLMAP_LIKE = Tolerances(reproj_px=1.0, merge_px=1.0, depth=0.01, normal_degrees=10.0)


@pytest.fixture(scope="module")
def true_maps(small_scene, tmp_path_factory):
    """The small scene's dense workspace with its ground-truth depth and normal maps as the final maps."""
    dense = tmp_path_factory.mktemp("fusion") / "dense"
    shutil.copytree(small_scene / "dense", dense)
    scene = load_scene(small_scene / "scene")
    for name in scene.image_names:
        write_map(map_path(dense / "stereo", "depth", name, "geometric"), scene.depth(name))
        write_map(map_path(dense / "stereo", "normal", name, "geometric"), scene.normal(name))
    return dense, scene, read_views(dense / "images", dense / "sparse", dense / "stereo")


def _read_visibility(path):
    words = np.frombuffer(path.read_bytes(), dtype="<u4")
    records, at = [], 2
    for _ in range(int(words[0])):
        records.append(frozenset(words[at + 1:at + 1 + words[at]].tolist()))
        at += 1 + words[at]
    return records


def _distance_to_truth(scene, points):
    o3d = open3d()
    rays = o3d.t.geometry.RaycastingScene()
    rays.add_triangles(o3d.t.io.read_triangle_mesh(str(scene.root / "gt" / "mesh.ply")))
    return rays.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy() / scene.extent


def test_at_colmaps_pixel_convention_and_merge_radius_it_is_colmaps_fusion(true_maps, tmp_path):
    dense, _, views = true_maps
    options = pycolmap.StereoFusionOptions()
    options.min_num_pixels, options.max_reproj_error = 2, COLMAP_LIKE.reproj_px
    options.max_depth_error, options.max_normal_error = COLMAP_LIKE.depth, COLMAP_LIKE.normal_degrees
    options.max_traversal_depth, options.num_threads = 2, 1
    pycolmap.stereo_fusion(str(tmp_path / "fused.ply"), str(dense), options=options, input_type="geometric",
                           output_type="PLY")
    theirs = np.asarray(open3d().io.read_point_cloud(str(tmp_path / "fused.ply")).points)
    ours = fuse(views, COLMAP_LIKE, min_pixels=2, pixel_centre=0.0)
    assert len(theirs) > 10000
    assert abs(len(ours.xyz) - len(theirs)) <= 0.001 * len(theirs)
    distance, nearest = cKDTree(theirs).query(ours.xyz)
    same = distance < 1e-6 * np.ptp(theirs, axis=0).max()
    assert same.mean() > 0.999
    write_visibility(tmp_path / "ours.vis", ours.view_counts, views.model_indices[ours.views])
    ours_seen, theirs_seen = _read_visibility(tmp_path / "ours.vis"), _read_visibility(tmp_path / "fused.ply.vis")
    agree = [ours_seen[i] == theirs_seen[j] for i, j in zip(np.flatnonzero(same), nearest[same])]
    assert np.mean(agree) > 0.999


def test_exact_maps_fuse_onto_the_true_surface_with_its_normals(true_maps):
    _, scene, views = true_maps
    cloud = fuse(views, Tolerances(1.0, 0.25, 0.03, 60.0), min_pixels=2)
    assert len(cloud.xyz) > 10000
    distance = _distance_to_truth(scene, cloud.xyz)
    assert np.median(distance) < 1e-4 and (distance < 1e-3).mean() > 0.99
    assert np.median(cloud.normals[:, 2]) > 0.99  # most of what the views see is the ground, normal +z
    # read through the pixel's corner (COLMAP's convention), the same maps put the points half a pixel aside
    aside = _distance_to_truth(scene, fuse(views, Tolerances(1.0, 0.25, 0.03, 60.0), 2, pixel_centre=0.0).xyz)
    assert np.median(aside) > 3 * np.median(distance)


def test_a_smaller_merge_radius_gives_a_denser_cloud_as_accurate(true_maps):
    _, scene, views = true_maps
    coarse = fuse(views, Tolerances(1.0, 1.0, 0.03, 60.0), min_pixels=2)
    fine = fuse(views, Tolerances(1.0, 0.25, 0.03, 60.0), min_pixels=2)
    assert len(fine.xyz) > 1.5 * len(coarse.xyz)
    assert (_distance_to_truth(scene, fine.xyz) < 1e-3).mean() > 0.99
    spacing = {name: np.median(cKDTree(c.xyz).query(c.xyz, k=2)[0][:, 1]) for name, c in (("coarse", coarse),
                                                                                            ("fine", fine))}
    assert spacing["fine"] < 0.8 * spacing["coarse"]


def test_a_pixel_agrees_only_within_every_tolerance(true_maps):
    """Exact maps with one view's depths 5 % too far: at 3 % of the depth that view joins almost no point
    (395 of its 49,480 depths, where far ground at a grazing angle meets the pixel by chance); at 10 % it
    joins as many as with its exact depths (40,737)."""
    _, _, views = true_maps
    far = views.depth.copy()
    far[0] *= 1.05
    shifted = type(views)(views.cameras, far, views.normal, views.colour, views.overlap, views.model_indices)
    strict = fuse(shifted, Tolerances(1.0, 1.0, 0.03, 60.0), min_pixels=2)
    loose = fuse(shifted, Tolerances(1.0, 1.0, 0.10, 60.0), min_pixels=2)
    exact = fuse(views, Tolerances(1.0, 1.0, 0.10, 60.0), min_pixels=2)
    assert np.count_nonzero(strict.views == 0) < 0.02 * np.count_nonzero(loose.views == 0)
    assert np.count_nonzero(loose.views == 0) > 0.95 * np.count_nonzero(exact.views == 0)


def test_the_cloud_and_its_visibility_are_written_as_colmap_writes_them(tmp_path):
    xyz = np.arange(15, dtype=np.float32).reshape(5, 3)
    normals = np.tile(np.float32([0, 0, 1]), (5, 1))
    colours = np.arange(15, dtype=np.uint8).reshape(5, 3)
    write_cloud(tmp_path / "fused.ply", xyz, normals, colours)
    assert vertex_count(tmp_path / "fused.ply") == 5
    cloud = open3d().io.read_point_cloud(str(tmp_path / "fused.ply"))
    np.testing.assert_array_equal(np.asarray(cloud.points), xyz)
    np.testing.assert_array_equal(np.asarray(cloud.normals), normals)
    np.testing.assert_allclose(np.asarray(cloud.colors) * 255, colours, atol=1e-4)
    write_visibility(tmp_path / "fused.ply.vis", np.array([2, 1, 3, 1, 2]), np.array([0, 1, 2, 0, 1, 2, 3, 1, 3]))
    assert np.frombuffer((tmp_path / "fused.ply.vis").read_bytes(), dtype="<u4").tolist() == \
        [5, 0, 2, 0, 1, 1, 2, 3, 0, 1, 2, 1, 3, 2, 1, 3]


def test_a_damaged_map_is_named_in_one_line(true_maps, tmp_path):
    dense, scene, _ = true_maps
    broken = tmp_path / "dense"
    shutil.copytree(dense, broken)
    name = scene.image_names[2]
    map_path(broken / "stereo", "depth", name, "geometric").write_bytes(b"640&480&1&" + b"\0" * 100)
    with pytest.raises(ValueError, match=f"map of {name} .*--force mvs"):
        read_views(broken / "images", broken / "sparse", broken / "stereo")


def test_maps_that_do_not_fit_in_free_memory_stop_with_one_line(true_maps, monkeypatch):
    """Fusion holds every view's maps at once; where they do not fit, the kernel would kill the run without a
    word, so it stops first, saying which option lowers the memory."""
    dense, _, views = true_maps
    n, height, width = views.depth.shape
    need = n * height * width * BYTES_PER_PIXEL
    assert fusion._available_memory() > 0  # read on this machine
    monkeypatch.setattr(fusion, "_available_memory", lambda: need - 1)
    with pytest.raises(ValueError, match=rf"{n} views at {width}x{height} need .* GB .*mvs\.max_image_size"):
        read_views(dense / "images", dense / "sparse", dense / "stereo")
    monkeypatch.setattr(fusion, "_available_memory", lambda: need)
    assert len(read_views(dense / "images", dense / "sparse", dense / "stereo").cameras) == n
