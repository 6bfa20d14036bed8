import numpy as np
import pytest

from recon.eval.surface import surface_metrics
from recon.surface.cleanup import clean_mesh
from recon.surface.options import MeshOptions
from recon.surface.poisson import ROBUST_SHARE, octree_depth, poisson_mesh
from recon.surface.tsdf import tsdf_mesh


def test_poisson_is_accurate_and_trimmed(small_scene):
    pts, nrm, col = small_scene.points(step=2)
    mesh = clean_mesh(poisson_mesh(pts, nrm, col, MeshOptions(depth=8)), MeshOptions(target_faces=0))
    m = surface_metrics(mesh, small_scene.info)
    assert m["fscore@0.002"] >= 93 and m["fscore@0.005"] >= 97
    # no balloon: nothing beyond the points' box grown by the margin
    lo, hi = pts.min(0), pts.max(0)
    margin = MeshOptions().bbox_margin * (hi - lo).max()
    assert np.all(mesh.vertices >= lo - margin - 1e-9) and np.all(mesh.vertices <= hi + margin + 1e-9)
    # vertex colours come from the points: the mean colour matches
    assert np.abs(mesh.visual.vertex_colors[:, :3].mean(0) - col.mean(0)).max() < 15


def test_poisson_density_trim_removes_unsupported_surface(small_scene):
    pts, nrm, _ = small_scene.points(step=3)
    loose = poisson_mesh(pts, nrm, options=MeshOptions(depth=7, density_quantile=0, trim_distance=0, bbox_margin=1))
    tight = poisson_mesh(pts, nrm, options=MeshOptions(depth=7))
    assert tight.area < loose.area
    assert surface_metrics(tight, small_scene.info)["accuracy@0.005"] > surface_metrics(loose, small_scene.info)["accuracy@0.005"]


@pytest.mark.parametrize("noise", [0.0, 0.001])
def test_tsdf_is_accurate(small_scene, noise):
    rng = np.random.default_rng(0)
    depths = [np.where(d > 0, d * (1 + rng.normal(0, noise, d.shape)), 0).astype(np.float32)
              for d in small_scene.depths]
    mesh = tsdf_mesh(depths, small_scene.images, small_scene.cameras, MeshOptions(method="tsdf", voxel_fraction=0.003))
    m = surface_metrics(mesh, small_scene.info)
    assert m["fscore@0.002"] >= (90 if noise == 0 else 80) and m["fscore@0.005"] >= 97
    assert mesh.visual.kind == "vertex"


def test_points_sparser_than_the_poisson_cells_leave_no_pinholes():
    """A unit sphere sampled every ~0.08 and meshed at depth 9 (cells of 0.004): the distance trim at 4
    cells alone would cut out every face between the points; it never cuts closer than their spacing."""
    n = 2000
    k = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1 - 2 * k / n), np.pi * (1 + 5**0.5) * k
    pts = np.column_stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])
    mesh = poisson_mesh(pts, pts, options=MeshOptions(depth=9, density_quantile=0))
    assert mesh.area == pytest.approx(4 * np.pi, rel=0.03)
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - 1).max() < 0.02


@pytest.mark.parametrize("spread", [2.2, 3.0, 4.9, 6.4, 7.9])
def test_stray_points_never_make_the_cells_coarser_than_the_depth_over_the_robust_extent(spread):
    # a cloud in the unit cube and three stray points out to `spread` along x: the octree spans them all
    points = np.vstack([np.random.default_rng(0).random((20_000, 3)), [[spread, 0.5, 0.5]] * 3])
    depth = octree_depth(points, 9)
    lo, hi = np.quantile(points, [ROBUST_SHARE, 1 - ROBUST_SHARE], axis=0)
    assert (points.max(0) - points.min(0)).max() / 2**depth <= (hi - lo).max() / 2**9
    assert depth <= 9 + 3


def test_a_few_stray_points_far_out_do_not_coarsen_the_poisson_mesh(small_scene):
    pts, nrm, _ = small_scene.points(step=3)
    lo, hi = pts.min(0), pts.max(0)
    rng = np.random.default_rng(1)
    # 0.05 % of the points scattered up to 4 extents away (a survey's stray fused points)
    n = max(len(pts) // 2000, 5)
    stray = lo + (rng.random((n, 3)) * 9 - 4) * (hi - lo)
    options = MeshOptions(depth=7)
    clean = poisson_mesh(pts, nrm, options=options)
    strayed = poisson_mesh(np.vstack([pts, stray]), np.vstack([nrm, rng.normal(size=(n, 3))]), options=options)
    # the same cells as without the strays: about as many faces, as accurate (Poisson at mesh.depth over the
    # strays' extent: 1,073 faces against 24,936)
    assert len(strayed.faces) > 0.7 * len(clean.faces)
    f_clean = surface_metrics(clean, small_scene.info)["fscore@0.002"]
    assert surface_metrics(strayed, small_scene.info)["fscore@0.002"] > f_clean - 5
