"""Surface metrics against a synthetic scene: perfect, noisy, partial and shifted reconstructions."""

import numpy as np
import pytest
import trimesh
from scipy.special import erf

from recon.eval.surface import normal_angles, observed_points, sample_mesh, surface_metrics, views_seeing
from recon.synth import render_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return render_scene(tmp_path_factory.mktemp("surface") / "scene", views=8, width=320, height=240, seed=2)


@pytest.fixture(scope="module")
def gt_mesh(scene):
    return trimesh.load(scene.mesh_path, process=False)


@pytest.fixture(scope="module")
def gt_samples(scene, gt_mesh):
    return sample_mesh(gt_mesh.vertices, gt_mesh.faces, 0.001 * scene.extent, seed=1)


def test_ground_truth_mesh_scores_perfect(scene, gt_mesh):
    m = surface_metrics(gt_mesh, scene)
    for tau in ("0.002", "0.005"):
        assert m[f"accuracy@{tau}"] == pytest.approx(100.0)
        assert m[f"completeness@{tau}"] == pytest.approx(100.0)
        assert m[f"fscore@{tau}"] == pytest.approx(100.0)
    assert m["threshold@0.002"] == pytest.approx(0.002 * scene.extent)
    assert m["accuracy_median"] < 1e-5 and m["completeness_median"] < 1e-5


def test_ground_truth_samples_score_perfect(scene, gt_samples):
    m = surface_metrics(gt_samples, scene)
    assert m["accuracy@0.002"] == pytest.approx(100.0)
    assert m["completeness@0.002"] > 99.5
    assert m["n_points"] == len(gt_samples)


def test_noise_lowers_accuracy_as_expected(scene, gt_samples):
    # isotropic noise of sigma = tau / 2: the distance to a locally flat surface is |N(0, sigma)| along
    # the normal, so accuracy@tau ~ erf(2 / sqrt(2)) = 95.4 %, and ~100 % at 2.5 tau
    tau = 0.002 * scene.extent
    rng = np.random.default_rng(0)
    noisy = gt_samples + rng.normal(scale=tau / 2, size=gt_samples.shape)
    m = surface_metrics(noisy, scene)
    assert m["accuracy@0.002"] == pytest.approx(100 * erf(2 / np.sqrt(2)), abs=1.5)
    assert m["accuracy@0.005"] > 99.8
    assert m["completeness@0.002"] > 99.0
    assert m["accuracy_median"] == pytest.approx(0.6745 * tau / 2, rel=0.1)  # median of |N(0, sigma)|


def test_half_cloud_is_half_complete(scene, gt_samples):
    half = gt_samples[gt_samples[:, 0] < 0]
    m = surface_metrics(half, scene)
    observed = observed_points(scene, 0.001 * scene.extent)
    share = 100 * np.mean(observed[:, 0] < 0)
    assert 35 < share < 65
    assert m["accuracy@0.002"] == pytest.approx(100.0)
    assert m["completeness@0.002"] == pytest.approx(share, abs=2.0)
    assert m["fscore@0.002"] == pytest.approx(2 * 100 * m["completeness@0.002"] / (100 + m["completeness@0.002"]))


def test_shifted_cloud_fails(scene, gt_samples):
    shifted = gt_samples + [0, 0, 10 * 0.005 * scene.extent]
    m = surface_metrics(shifted, scene)
    assert m["accuracy@0.005"] < 20  # only points that happen to land near another surface
    assert m["completeness@0.005"] < 20


def test_input_types_agree(scene, gt_samples, tmp_path):
    from recon._open3d import open3d

    o3d = open3d()
    pts = gt_samples[::20]
    ref = surface_metrics(pts, scene)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    path = tmp_path / "cloud.ply"
    trimesh.PointCloud(pts).export(path)
    for other in (pcd, o3d.t.geometry.PointCloud.from_legacy(pcd), path, trimesh.PointCloud(pts)):
        m = surface_metrics(other, scene)
        assert m["n_points"] == len(pts)
        assert m["completeness@0.002"] == pytest.approx(ref["completeness@0.002"], abs=1e-3)
        assert m["accuracy@0.002"] == pytest.approx(ref["accuracy@0.002"], abs=1e-3)
    with pytest.raises(TypeError):
        surface_metrics(object(), scene)


def test_observed_points_are_on_the_surface_and_thinned(scene, gt_mesh):
    spacing = 0.001 * scene.extent
    pts = observed_points(scene, spacing)
    # back-projected depth lies on the mesh (float32 depth precision)
    from recon._open3d import open3d

    o3d = open3d()
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(np.asarray(gt_mesh.vertices, np.float32)),
                     o3d.core.Tensor(np.asarray(gt_mesh.faces, np.uint32)))
    dist = rc.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    assert np.max(dist) < 1e-4 * scene.extent
    # one point per voxel: no two points share a voxel
    keys = np.floor(pts / spacing).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(pts)


def test_views_seeing_counts_the_views_whose_true_depth_holds_the_point(scene):
    from recon.geometry.transforms import backproject

    points = observed_points(scene, 0.002 * scene.extent)
    count = views_seeing(scene, points)
    assert count.min() >= 1 and count.max() <= len(scene.cameras())  # each is some view's depth
    assert count.mean() > 2  # an orbit: most of the surface is seen by several views
    # the points one view's depth map gives, moved off the surface along its normal by 2 % of the extent
    name, cam = next(iter(scene.cameras().items()))
    depth = scene.depth(name)
    v, u = np.nonzero(depth > 0)
    on = backproject(cam.K, cam.R, cam.t, np.column_stack([u + 0.5, v + 0.5]), depth[v, u])
    off = on + 0.02 * scene.extent * (scene.normal(name)[v, u] @ cam.R)
    assert views_seeing(scene, on).min() >= 1
    assert np.mean(views_seeing(scene, off) == 0) > 0.97  # (not those at a concave corner: on the other face)


def test_object_metrics_take_a_point_cloud_too():
    from recon.eval.surface import object_metrics

    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    on_it = sample_mesh(ball.vertices, ball.faces, 0.002, seed=3)
    m = object_metrics(on_it, ball)
    assert m["accuracy@0.002"] > 99.9 and m["completeness@0.002"] > 99.0
    half = on_it[on_it[:, 2] > 0]
    m = object_metrics(np.concatenate([half, half[:1000] + [2.0, 0, 0]]), ball)  # half of it, and a stray piece
    assert 45 < m["completeness@0.002"] < 55 and m["accuracy@0.002"] < 100 * len(half) / (len(half) + 999)


def test_object_metrics_count_only_the_surface_a_view_sees_when_told_which():
    """An object on a table: its underside no photo sees does not count against a reconstruction of
    what the photos show, but it does when every sample counts."""
    from recon.eval.surface import object_metrics

    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    upper = sample_mesh(ball.vertices, ball.faces, 0.002, seed=3)
    upper = upper[upper[:, 2] > -0.3]
    seen = object_metrics(upper, ball, observable=lambda p: p[:, 2] > -0.3)
    whole = object_metrics(upper, ball)
    assert seen["completeness@0.002"] > 99.0
    assert whole["completeness@0.002"] < 90.0
    assert seen["accuracy@0.002"] == whole["accuracy@0.002"]


def test_normal_angles_are_zero_on_the_truth_and_grow_with_bumps(scene, gt_mesh):
    limit = 0.002 * scene.extent
    assert normal_angles(gt_mesh.vertices, gt_mesh.faces, scene, limit).max() < 0.01
    assert len(normal_angles(gt_mesh.vertices + scene.extent, gt_mesh.faces, scene, limit)) == 0  # none near the truth
    fine = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(gt_mesh.vertices, gt_mesh.faces, 4 * limit), process=False)
    bumpy = fine.vertices + np.random.default_rng(0).normal(0, limit / 4, fine.vertices.shape)
    angles = normal_angles(bumpy, fine.faces, scene, limit)
    assert len(angles) > 1000 and np.median(angles) > 5
