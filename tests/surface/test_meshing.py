from dataclasses import replace

import numpy as np
import pytest
import trimesh
from surface_scene import sphere_points

from recon.eval.surface import surface_metrics
from recon.surface.cleanup import clean_mesh
from recon.surface.options import MeshOptions
from recon.surface.poisson import MAX_CELL_SPACINGS, MIN_CUBE_SCALE, octree, poisson_cell, poisson_mesh
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


def test_poisson_cells_do_not_jump_as_stray_points_move_out():
    # a cloud in the unit cube and three stray points along x, from 1.5 to 12 cube sides out: the octree
    # needs more levels to span them, and its cells stay the asked size all the same
    spacing = 0.02  # about the 20,000 points' nearest-neighbour distance: far from binding the cells
    levels = set()
    for x in np.geomspace(1.5, 12, 25):
        points = np.vstack([np.random.default_rng(0).random((20_000, 3)), [[x, 0.5, 0.5]] * 3])
        cell = poisson_cell(points, 9, spacing)
        assert cell == pytest.approx(poisson_cell(points[:-3], 9, spacing), rel=0.01)
        depth, scale = octree(points, cell, 9)
        assert scale >= MIN_CUBE_SCALE and scale * np.ptp(points, axis=0).max() / 2**depth == pytest.approx(cell)
        levels.add(depth)
    assert len(levels) >= 3


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


def test_a_wide_sparse_surface_with_many_points_does_not_coarsen_the_dense_one(monkeypatch):
    """A ball sampled densely and a ground 60 times wider holding 3 % of the points (far ground a
    walk finds at grazing angles): too many to leave out as strays, so the cells of the whole extent
    would be near the ball's radius; held within MAX_CELL_SPACINGS times the points' spacing, the
    ball keeps its shape."""
    ball = sphere_points(80_000)
    xy = (np.random.default_rng(0).random((2400, 2)) - 0.5) * 60
    ground = np.column_stack([xy, np.full(len(xy), -1.5)])
    points = np.vstack([ball, ground])
    normals = np.vstack([ball, np.tile([0.0, 0.0, 1.0], (len(ground), 1))])

    def radial_error(bound):
        monkeypatch.setattr("recon.surface.poisson.MAX_CELL_SPACINGS", bound)
        vertices = np.asarray(poisson_mesh(points, normals, options=MeshOptions(depth=6, density_quantile=0)).vertices)
        radius = np.linalg.norm(vertices, axis=1)
        return np.median(np.abs(radius[radius < 1.3] - 1)), np.count_nonzero(radius < 1.3)

    error, count = radial_error(MAX_CELL_SPACINGS)
    assert error < 0.01 and count > 300
    error, count = radial_error(1e9)  # the cells of the extent alone: the ball is a few blobs
    assert error > 0.05 or count < 50
