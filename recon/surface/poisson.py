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


def nearest_distances(tree: cKDTree) -> np.ndarray:
    """Each point's distance to its nearest other point (empty with under two points)."""
    if tree.n < 2:
        return np.zeros(0)
    nearest, _ = tree.query(tree.data, k=2, workers=-1)
    return nearest[:, 1]


def point_gap(nearest: np.ndarray) -> float:
    """Twice the 90th percentile of the points' nearest-neighbour distances (:func:`nearest_distances`):
    the distance trim never cuts closer than this, or it punches holes between points spaced wider than
    its Poisson cells (a masked object at 320x240: points 4.6 cells apart, 14 % of the faces cut out as
    pinholes, 11,669 boundary edges against 518, held-out coverage 0.85)."""
    return 2.0 * float(np.percentile(nearest, 90)) if len(nearest) else 0.0


#: the points' extent that sets Poisson's cell size leaves out this share of them at each end of each axis
ROBUST_SHARE = 0.001
#: Poisson's cells are this many times the robust extent / 2^``mesh.depth``: the cells a compact cloud
#: (its full extent about 1.1 times its robust one) got when the octree spanned its whole box ...
CELL_FACTOR = 1.2
#: ... and at most this many times the points' median nearest-neighbour distance
MAX_CELL_SPACINGS = 20.0
#: open3d's octree cube is at least this many times the points' box (its default)
MIN_CUBE_SCALE = 1.1
#: the octree goes at most this many levels deeper than ``mesh.depth``; past that its cells are coarser
MAX_EXTRA_LEVELS = 4


def robust_extent(points: np.ndarray) -> float:
    """The largest side of the points' box without their farthest :data:`ROBUST_SHARE` at each end of
    each axis."""
    lo, hi = np.quantile(points, [ROBUST_SHARE, 1.0 - ROBUST_SHARE], axis=0)
    return float((hi - lo).max())


def poisson_cell(points: np.ndarray, depth: int, spacing: float) -> float:
    """The side of Poisson's finest cells: :data:`CELL_FACTOR` times the points' extent without their
    farthest 0.1 % per axis (:func:`robust_extent`) / 2^``depth``, at most :data:`MAX_CELL_SPACINGS`
    times their median nearest-neighbour distance ``spacing``. The distance trim counts in these cells.

    Not the extent of every point: a few stray points far out (a nadir survey's fused cloud: 919 of
    549,615 points, every one off the true surface, spread it 4.5 times wider than the rest) would make
    every cell coarser by that factor (aerial_grid's mesh: 19,832 faces of 250,000 allowed). The cap on
    the spacing: where more than 0.1 % of the points lie far out and are true (far ground found at
    grazing angles), they widen the robust extent itself. far_field's cloud with PatchMatch testing the
    ground's normal (recon.mvs.ground_normal) spreads to 105 m against 51 m, and its cells to 47 times its
    points' 5.6 mm spacing near the shed (mesh F@0.2 % .708 in cells of 1.1 times the robust extent
    / 2^depth; .977 with the cap). Uncapped, the zoo's other clouds have cells of 0.7 to 9.6 times
    their points' spacing (transient_car's 9.6, the objects' 0.7-1.3); far_field's own without the
    ground's normal 21, which the cap makes 5 % finer. Cells from the spacing alone trade the zoo's
    scenes against each other: the scenes whose completeness is short (sparse far ground, surface few
    views see) want coarser cells than their spacing, the ones whose accuracy is short finer
    (docs/DECISIONS.md)."""
    cell = CELL_FACTOR * robust_extent(points) / 2**depth
    return min(cell, MAX_CELL_SPACINGS * spacing) if spacing > 0 else cell


def octree(points: np.ndarray, cell: float, depth: int) -> tuple[int, float]:
    """open3d's octree depth and scale (its cube's side over the largest side of the points' box) that
    make its finest cells ``cell`` wide: the shallowest depth whose cube, at least
    :data:`MIN_CUBE_SCALE` times the box, holds the points, the cube padded to fit. At most
    :data:`MAX_EXTRA_LEVELS` deeper than ``depth`` (points piled on each other make the spacing tiny),
    where the cells are coarser than ``cell``.

    Exact cells rather than whole levels: the levels a few far points add to the octree were rounded
    before, so the cells jumped by up to twice as a point moved. walkaround's cloud with PatchMatch
    testing the ground's normal has a few points 61 m out (29.5 m without), and its octree went two
    levels deeper, cells of 0.03 m instead of 0.06 m (mesh F@0.2 % .845 -> .837; .850 in exact
    cells); facade_walk's cloud, spread 1.94 times wider than its robust extent (under the 2 that added
    a level), had cells 1.8 times a compact cloud's (mesh F .954; .969 in exact cells, zoo:
    docs/DECISIONS.md)."""
    full = float((points.max(0) - points.min(0)).max())
    if full <= 0 or cell <= 0:
        return depth, MIN_CUBE_SCALE
    levels = min(max(int(np.ceil(np.log2(MIN_CUBE_SCALE * full / cell))), 1), depth + MAX_EXTRA_LEVELS)
    return levels, max(MIN_CUBE_SCALE, cell * 2**levels / full)


def poisson_mesh(points: np.ndarray, normals: np.ndarray, colors: np.ndarray | None = None,
                 options: MeshOptions = MeshOptions()) -> trimesh.Trimesh:
    """Screened Poisson surface of oriented points (N, 3) with normals (N, 3), trimmed; vertex colours
    (uint8) come from the nearest point's colour (``colors``: N x 3, uint8) when given."""
    o3d = open3d()
    points = np.asarray(points, np.float64)
    turned = points @ OBLIQUE.T
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(turned))
    pcd.normals = o3d.utility.Vector3dVector(np.asarray(normals, np.float64) @ OBLIQUE.T)
    tree = cKDTree(points)
    nearest = nearest_distances(tree)
    spacing = float(np.median(nearest)) if len(nearest) else 0.0
    cell = poisson_cell(turned, options.depth, spacing)
    depth, scale = octree(turned, cell, options.depth)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pcd, depth=depth, scale=scale, point_weight=options.point_weight,
            n_threads=1 if options.deterministic else -1)
    vertices = np.asarray(mesh.vertices) @ OBLIQUE
    faces = np.asarray(mesh.triangles)
    density = np.asarray(density)
    log.info("poisson: cells of %.4g (mesh.depth %d; the points' median spacing %.3g), octree depth %d: "
             "%d vertices, %d faces from %d points", cell, options.depth, spacing, depth, len(vertices),
             len(faces), len(points))

    keep_vertex = np.ones(len(vertices), bool)
    if options.density_quantile > 0:
        keep_vertex &= density >= min(np.quantile(density, options.density_quantile),
                                      np.median(density) - options.density_levels)
    lo, hi = points.min(0), points.max(0)
    margin = options.bbox_margin * (hi - lo).max()
    keep_vertex &= np.all((vertices >= lo - margin) & (vertices <= hi + margin), axis=1)
    keep_face = keep_vertex[faces].all(axis=1)
    if options.trim_distance > 0:
        centroids = vertices[faces].mean(axis=1)
        reach = max(options.trim_distance * cell, point_gap(nearest))
        dist, _ = tree.query(centroids, distance_upper_bound=reach, workers=-1)
        keep_face &= np.isfinite(dist)
    out = trimesh.Trimesh(vertices, faces[keep_face], process=False)
    out.remove_unreferenced_vertices()
    if colors is not None:
        _, nearest = tree.query(out.vertices, workers=-1)
        out.visual.vertex_colors = np.asarray(colors, np.uint8)[nearest]
    log.info("poisson trimmed to %d faces", len(out.faces))
    return out
