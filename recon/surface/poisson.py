"""Screened Poisson surface reconstruction from oriented points, trimmed to where the points are.

Poisson closes every surface it builds: the open sides of a scene (sky, the far side of a facade) come
back as smooth balloon surfaces far from any point. Three trims remove them: vertices of low point
density, faces outside the points' bounding box grown by a margin, and faces farther than a few octree
cells (or than the points' own spacing, where they lie sparser) from any point.

open3d reports a vertex's density as the octree depth its nearby points support: one level less, points
twice as far apart. A vertex is cut when its density is among the lowest ``density_quantile`` of the
mesh's AND more than ``density_levels`` below the median vertex's. The quantile alone cuts its share of
every mesh; where nothing is unsupported (a closed object masked from its table, or on a turntable) that
share is true surface, and the held-out views saw holes through it. The levels alone (one below the
median) cut too much of an open scene whose true surface is sparsely seen: walkaround's mesh F@0.2 %
.829 -> .754. With the quantile, 1.5 levels rather than 1: a part of an object whose points lie twice as
far apart as elsewhere (turntable_black's dark lower vase, which the depth maps hardly hold) sits one
level below the median and was cut, and the held-out views saw the plinth through the hole; zoo:
held-out coverage up on 6 of 15 scenes and down on none, mesh F@0.2 % mean and worst up. 2 levels
rather than 1.5: the flat grey sides of clutter's large cans, whose depth maps hold only their rims, are
kept where Poisson closes them; zoo: held-out coverage mean and worst up, mesh F@0.2 % worst up and mean
unchanged (docs/DECISIONS.md).
"""

from __future__ import annotations

import logging

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from recon._open3d import open3d
from recon.geometry.transforms import axis_angle_rotation
from recon.surface.options import MeshOptions

log = logging.getLogger(__name__)


#: Poisson's octree is aligned with the axes; surfaces parallel to its cells' faces (the ground and
#: walls of a levelled model, recon/sparse/frame.py) come out worse: on the 24-view synthetic scene mesh
#: F@0.2 % was 0.931 with the levelled frame's axes against 0.954-0.960 in three random frames. So the
#: points are turned into this fixed oblique frame for Poisson, and the mesh back.
OBLIQUE = axis_angle_rotation(np.array([1.0, 2.0, 3.0]), 0.6)  # no axis of it along a levelled frame's


def point_gap(tree: cKDTree) -> float:
    """Twice the 90th percentile of the points' nearest-neighbour distances: the distance trim never
    cuts closer than this, or it punches holes between points spaced wider than its Poisson cells (a
    masked object at 320x240: points 4.6 cells apart, 14 % of the faces cut out as pinholes, 11,669
    boundary edges against 518, held-out coverage 0.85)."""
    if tree.n < 2:
        return 0.0
    nearest, _ = tree.query(tree.data, k=2, workers=-1)
    return 2.0 * float(np.percentile(nearest[:, 1], 90))


#: the points' extent that sets Poisson's cell size leaves out this share of them at each end of each axis
ROBUST_SHARE = 0.001
MAX_EXTRA_LEVELS = 3


def robust_extent(points: np.ndarray) -> float:
    """The largest side of the points' box without their farthest :data:`ROBUST_SHARE` at each end of
    each axis."""
    lo, hi = np.quantile(points, [ROBUST_SHARE, 1.0 - ROBUST_SHARE], axis=0)
    return float((hi - lo).max())


def trim_cell(points: np.ndarray, depth: int, octree: int) -> float:
    """The cell the distance trim counts in: the octree's (the points' extent / 2^``octree``), or,
    where stray points added levels (``octree`` > ``depth``), the robust extent / 2^``depth``: the
    cell the options ask for. The added levels are rounded; the trim should not jump with them.
    Trimming in the octree's cells, aerial_grid's cloud with two-view depth maps (4.94 times the
    robust extent, 2.30 doublings, two levels) kept Poisson's bridges over its holes 1.23 times as
    far out as asked: mesh F@0.2 % .660, against .703 in the asked cells (its default cloud, 2.67
    doublings and three levels: .676 against .691)."""
    if octree > depth:
        return robust_extent(points) / 2**depth
    return float((points.max(0) - points.min(0)).max()) / 2**octree


def octree_depth(points: np.ndarray, depth: int) -> int:
    """The octree depth that gives cells of ``extent / 2^depth``, where the extent is that of the points
    without their farthest 0.1 % per axis. Poisson's octree spans every point: a few stray points far
    out (a nadir survey's fused cloud: 919 of 549,615 points, every one off the true surface, spread it
    4.5 times wider than the rest) would otherwise make every cell coarser by that factor (aerial_grid's
    mesh: 19,832 faces of 250,000 allowed). Where the full extent is at least twice that extent, as many
    levels more as it has doublings, rounded, at most three; the octree is adaptive, so the empty space
    costs little. Not below twice: far_field's far ground, sparse but true, spreads its points 1.57 times
    wider than the robust extent, and a level more there cut its sparse far ground to holes (mesh F@0.2 %
    0.778 -> 0.686). Rounded up instead, cells are never coarser than asked, but up to twice finer:
    walkaround with two-view depth maps (1.13 doublings) lost mesh F .703 -> .652 to holes."""
    robust = robust_extent(points)
    full = float((points.max(0) - points.min(0)).max())
    if robust <= 0 or full < 2 * robust:
        return depth
    return depth + min(int(np.round(np.log2(full / robust))), MAX_EXTRA_LEVELS)


def poisson_mesh(points: np.ndarray, normals: np.ndarray, colors: np.ndarray | None = None,
                 options: MeshOptions = MeshOptions()) -> trimesh.Trimesh:
    """Screened Poisson surface of oriented points (N, 3) with normals (N, 3), trimmed; vertex colours
    (uint8) come from the nearest point's colour (``colors``: N x 3, uint8) when given."""
    o3d = open3d()
    points = np.asarray(points, np.float64)
    turned = points @ OBLIQUE.T
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(turned))
    pcd.normals = o3d.utility.Vector3dVector(np.asarray(normals, np.float64) @ OBLIQUE.T)
    depth = octree_depth(turned, options.depth)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pcd, depth=depth, point_weight=options.point_weight, n_threads=1 if options.deterministic else -1)
    vertices = np.asarray(mesh.vertices) @ OBLIQUE
    faces = np.asarray(mesh.triangles)
    density = np.asarray(density)
    log.info("poisson depth %d (mesh.depth %d over the points' extent without stray points): %d vertices, "
             "%d faces from %d points", depth, options.depth, len(vertices), len(faces), len(points))

    keep_vertex = np.ones(len(vertices), bool)
    if options.density_quantile > 0:
        keep_vertex &= density >= min(np.quantile(density, options.density_quantile),
                                      np.median(density) - options.density_levels)
    lo, hi = points.min(0), points.max(0)
    margin = options.bbox_margin * (hi - lo).max()
    keep_vertex &= np.all((vertices >= lo - margin) & (vertices <= hi + margin), axis=1)
    keep_face = keep_vertex[faces].all(axis=1)
    tree = cKDTree(points)
    if options.trim_distance > 0:
        cell = trim_cell(points, options.depth, depth)
        centroids = vertices[faces].mean(axis=1)
        dist, _ = tree.query(centroids, distance_upper_bound=max(options.trim_distance * cell, point_gap(tree)),
                             workers=-1)
        keep_face &= np.isfinite(dist)
    out = trimesh.Trimesh(vertices, faces[keep_face], process=False)
    out.remove_unreferenced_vertices()
    if colors is not None:
        _, nearest = tree.query(out.vertices, workers=-1)
        out.visual.vertex_colors = np.asarray(colors, np.uint8)[nearest]
    log.info("poisson trimmed to %d faces", len(out.faces))
    return out
