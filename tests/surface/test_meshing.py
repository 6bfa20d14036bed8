from dataclasses import replace

import numpy as np
import pytest
import trimesh
from surface_scene import sphere_points

from recon.eval.surface import surface_metrics
from recon.surface.cleanup import clean_mesh
from recon.surface.options import MeshOptions
from recon.surface.poisson import octree_depth, poisson_mesh, trim_cell
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


def test_an_evenly_sampled_closed_surface_loses_nothing_to_the_density_trim():
    """The lowest 5 % of an evenly sampled sphere's vertex densities are no sparser than the rest: the
    quantile alone cut them out as holes."""
    pts = sphere_points(20_000)
    kept = poisson_mesh(pts, pts, options=MeshOptions(depth=7))
    assert kept.area == pytest.approx(4 * np.pi, rel=0.002)
    assert len(trimesh.grouping.group_rows(kept.edges_sorted, require_count=1)) == 0  # no boundary: no hole
    holed = poisson_mesh(pts, pts, options=MeshOptions(depth=7, density_levels=0))  # the quantile alone
    assert holed.area < 0.99 * 4 * np.pi


def test_a_part_of_a_closed_surface_seen_half_as_densely_is_kept():
    """A cap of the sphere with a quarter of its points (twice their spacing: one octree level sparser
    than the rest, as a dark part of an object the depth maps hardly hold): at one level the trim cut it."""
    pts = sphere_points(20_000)
    cap = pts[:, 2] < -0.7
    pts = pts[~cap | (np.random.default_rng(0).random(len(pts)) < 0.25)]
    kept = poisson_mesh(pts, pts, options=MeshOptions(depth=7))
    assert kept.area == pytest.approx(4 * np.pi, rel=0.002)
    holed = poisson_mesh(pts, pts, options=MeshOptions(depth=7, density_levels=1.0))
    assert holed.area < 0.95 * 4 * np.pi


def test_a_part_of_a_closed_surface_seen_a_sixth_as_densely_is_kept():
    """A cap of the sphere with a sixth of its points (2.4 times their spacing, 1.3 octree levels sparser
    than the rest, as the untextured side of a can whose depth maps hold only its rims): at 1.5 levels the
    trim cut most of it."""
    pts = sphere_points(20_000)
    cap = pts[:, 2] < -0.7
    pts = pts[~cap | (np.random.default_rng(0).random(len(pts)) < 1 / 6)]
    kept = poisson_mesh(pts, pts, options=MeshOptions(depth=7))
    assert kept.area == pytest.approx(4 * np.pi, rel=0.005)
    holed = poisson_mesh(pts, pts, options=MeshOptions(depth=7, density_levels=1.5))
    assert holed.area < 0.96 * 4 * np.pi


def test_the_density_trim_still_cuts_what_no_point_supports():
    """A hemisphere: Poisson closes it with a balloon over the open side, whose vertices lie far sparser
    than the median; with the other trims off, the density trim alone takes it, and only it."""
    pts = sphere_points(20_000)
    pts = pts[pts[:, 2] > 0]
    loose = MeshOptions(depth=7, trim_distance=0, bbox_margin=1)
    untrimmed = poisson_mesh(pts, pts, options=replace(loose, density_quantile=0))
    trimmed = poisson_mesh(pts, pts, options=loose)
    assert untrimmed.area > 1.3 * 2 * np.pi
    # a rim of the balloon next to the points stays (1.10 of the area at two levels, 1.05 at 1.5); the
    # other trims take it (1.02 with them on)
    assert trimmed.area < 1.15 * 2 * np.pi
    every_trim = poisson_mesh(pts, pts, options=MeshOptions(depth=7))
    assert every_trim.area == pytest.approx(2 * np.pi, rel=0.03)
    assert np.abs(np.linalg.norm(every_trim.vertices, axis=1) - 1).max() < 0.02


def test_points_sparser_than_the_poisson_cells_leave_no_pinholes():
    """A unit sphere sampled every ~0.08 and meshed at depth 9 (cells of 0.004): the distance trim at 4
    cells alone would cut out every face between the points; it never cuts closer than their spacing."""
    pts = sphere_points(2000)
    mesh = poisson_mesh(pts, pts, options=MeshOptions(depth=9, density_quantile=0))
    assert mesh.area == pytest.approx(4 * np.pi, rel=0.03)
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - 1).max() < 0.02


@pytest.mark.parametrize("spread", [2 ** 1.5, 2 ** 2.5])  # where the octree levels the strays add round up
def test_the_distance_trim_does_not_jump_where_the_stray_levels_round(spread):
    # a cloud in the unit cube and three stray points along x, just short of and just past `spread`
    def cloud(x):
        return np.vstack([np.random.default_rng(0).random((20_000, 3)), [[x, 0.5, 0.5]] * 3])

    short, past = cloud(0.97 * spread), cloud(1.03 * spread)
    levels = octree_depth(short, 9), octree_depth(past, 9)
    assert levels[1] == levels[0] + 1  # the octree's cells halve...
    cells = trim_cell(short, 9, levels[0]), trim_cell(past, 9, levels[1])
    assert cells[1] == pytest.approx(cells[0], rel=0.01)  # ...the trim's do not


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
