"""Visibility-based Delaunay surface: the fused points are tetrahedralized, every tetrahedron is labelled
inside or outside by a minimum s-t cut, and the surface is the facets between the two labels
(Labatut, Pons and Keriven 2009, "Robust and efficient surface reconstruction from range data";
OpenMVS's ReconstructMesh works this way).

The points are first thinned to one per cell (half a Poisson cell at ``mesh.depth``). Each view that
agrees with a point (its depth map holds the point's depth at the point's pixel) votes along its line
of sight: every facet the segment from the point to the camera crosses costs 1 to become surface facing
that camera, the tetrahedron just behind the point is linked to the sink (occupied), and the one
holding the camera, or where the line leaves the points' hull, to the source (free). The space around
the hull is free too, so an inside tetrahedron's hull facet is surface where views look at it from
outside (an object's convex side), and not where none does (the hull's underside, below a terrain).
A surface-quality term (Labatut et al.'s 1 - min(cos phi, cos psi), phi and psi the angles between a
facet and its two tetrahedra's circumspheres) makes facets cutting across the sampled surface, whose
circumspheres are small and centred near them, dearer than facets lying in it. Stray points carry few
lines of sight and are cut away; the surface passes through the points themselves, so it keeps their
detail wherever they are dense, whatever their spacing elsewhere. Faces far longer than a cell are
dropped afterwards (:data:`MAX_EDGE_CELLS`).

Against Poisson on the zoo (docs/DECISIONS.md): more accurate where the cloud holds weakly supported
points off the surface or a few far strays, which bend Poisson's surface or coarsen its cells; rougher
elsewhere, as the surface goes through every point's noise, and its textures render less sharply.

Our own: COLMAP's Delaunay mesher needs CGAL, which pycolmap's wheels are built without (pycolmap
4.2 has its options but no function), and open3d and trimesh have none. scipy's Delaunay (Qhull)
tetrahedralizes, numba walks the lines of sight, PyMaxflow cuts.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable

import numpy as np
import trimesh
from numba import njit
from scipy.spatial import Delaunay, QhullError, cKDTree

from recon.mvs.free_space import agreeing_points
from recon.mvs.views import ViewCamera
from recon.surface.options import MeshOptions
from recon.surface.poisson import robust_extent

log = logging.getLogger(__name__)


@njit(cache=True)
def _barycentric(transform, tet, x, out):  # pragma: no cover - numba
    """The four barycentric coordinates of ``x`` in tetrahedron ``tet`` (scipy's affine transform), into
    ``out``."""
    last = 1.0
    for k in range(3):
        v = 0.0
        for m in range(3):
            v += transform[tet, k, m] * (x[m] - transform[tet, 3, m])
        out[k] = v
        last -= v
    out[3] = last


@njit(cache=True)
def _locate(transform, neighbors, start, x, max_steps, b):  # pragma: no cover - numba
    """The tetrahedron holding ``x``, walking from ``start`` towards it; -1 outside the hull. ``b``: a
    buffer of 4."""
    tet = start
    for _ in range(max_steps):
        _barycentric(transform, tet, x, b)
        worst = 0
        for k in range(1, 4):
            if b[k] < b[worst]:
                worst = k
        if not b[worst] >= -1e-12:  # (also NaN: a flat tetrahedron)
            nxt = neighbors[tet, worst]
            if nxt < 0:
                return -1
            tet = nxt
        else:
            return tet
    return tet


@njit(cache=True)
def _cast(points, centres, ray_point, ray_view, vertex_tet, transform, neighbors, step, weight,
          facet_in, source, sink):  # pragma: no cover - numba
    """Walk every line of sight (point ``ray_point[r]`` to camera ``ray_view[r]``) through the
    tetrahedra, adding ``weight`` to each facet it crosses (``facet_in[tet, k]``: the capacity of the
    edge from the neighbour across facet k into ``tet``), to the source link of the tetrahedron where it
    reaches the camera or leaves the hull, and to the sink link of the one just behind the point."""
    x = np.empty(3)
    d = np.empty(3)
    b = np.empty(4)
    rate = np.empty(4)
    for r in range(ray_point.shape[0]):
        p, c = ray_point[r], ray_view[r]
        length = 0.0
        for m in range(3):
            d[m] = centres[c, m] - points[p, m]
            length += d[m] * d[m]
        length = math.sqrt(length)
        if length <= 0.0:
            continue
        t0 = step[p] / length
        for m in range(3):
            x[m] = points[p, m] - t0 * d[m]
        behind = _locate(transform, neighbors, vertex_tet[p], x, 1000, b)
        if behind >= 0:
            sink[behind] += weight
        for m in range(3):
            x[m] = points[p, m] + t0 * d[m]
        tet = _locate(transform, neighbors, vertex_tet[p], x, 1000, b)
        if tet < 0:
            continue
        t = t0
        for _ in range(100000):
            _barycentric(transform, tet, x, b)
            last = 0.0
            for k in range(3):
                v = 0.0
                for m in range(3):
                    v += transform[tet, k, m] * d[m]
                rate[k] = v
                last -= v
            rate[3] = last
            exit_t, exit_k = math.inf, -1
            for k in range(4):
                if rate[k] < 0.0:
                    tk = t - b[k] / rate[k]
                    if tk < exit_t:
                        exit_t, exit_k = tk, k
            if exit_k < 0 or exit_t >= 1.0:
                source[tet] += weight
                break
            nxt = neighbors[tet, exit_k]
            if nxt < 0:
                source[tet] += weight
                break
            facet_in[tet, exit_k] += weight
            t = max(exit_t, t)
            for m in range(3):
                x[m] = points[p, m] + t * d[m]
            tet = nxt


def lines_of_sight(points: np.ndarray, views: Iterable[tuple[ViewCamera, np.ndarray]], agree: float):
    """(point index, view index) of every view whose depth map agrees with a point, and the views' centres."""
    ray_point, ray_view, centres = [], [], []
    for cam, depth in views:
        seen = np.flatnonzero(agreeing_points(points, cam, depth, agree))
        ray_point.append(seen)
        ray_view.append(np.full(len(seen), len(centres), np.int64))
        centres.append(-cam.R.T @ cam.t)
    return np.concatenate(ray_point), np.concatenate(ray_view), np.asarray(centres, np.float64)


def thin(points: np.ndarray, cell: float) -> np.ndarray:
    """Indices of one point per ``cell``-sized voxel (the one nearest the voxel's centre)."""
    idx = np.floor(points / cell).astype(np.int64)
    off = np.linalg.norm(points / cell - idx - 0.5, axis=1)
    order = np.lexsort((off, idx[:, 2], idx[:, 1], idx[:, 0]))
    keys = idx[order]
    first = np.ones(len(order), bool)
    first[1:] = np.any(keys[1:] != keys[:-1], axis=1)
    return np.sort(order[first])


#: the vertices of facet k of a tetrahedron (the facet opposite its vertex k)
_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def _facet_quality(tri: Delaunay) -> np.ndarray:
    """(T, 4): 1 - cos of the angle between facet k of each tetrahedron and the tetrahedron's circumsphere;
    0 where the circumsphere's centre lies far from the facet's plane (a facet flat in the sampled
    surface), 1 where it lies in the plane or the tetrahedron is flat."""
    p = tri.points[tri.simplices]  # T, 4, 3
    a, b, c = (p[:, k] - p[:, 0] for k in (1, 2, 3))
    bc, ca, ab = np.cross(b, c), np.cross(c, a), np.cross(a, b)
    with np.errstate(all="ignore"):
        centre = p[:, 0] + ((a * a).sum(1)[:, None] * bc + (b * b).sum(1)[:, None] * ca
                            + (c * c).sum(1)[:, None] * ab) / (2.0 * (a * bc).sum(1))[:, None]
        radius = np.linalg.norm(centre - p[:, 0], axis=1)
        out = np.empty((len(p), 4))
        for k in range(4):
            face = p[:, _OTHERS[k]]
            n = np.cross(face[:, 1] - face[:, 0], face[:, 2] - face[:, 0])
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            cosine = np.abs(((centre - face[:, 0]) * n).sum(1)) / radius
            out[:, k] = 1.0 - np.clip(np.nan_to_num(cosine, nan=0.0, posinf=0.0), 0.0, 1.0)
    return out


#: weight of the surface-quality term, against 1 per line of sight crossing a facet
QUALITY_WEIGHT = 1.0
#: faces with an edge longer than this many thinning cells are dropped: facets between a labelled-inside
#: pocket and the free space, far from every point. Zoo at 640x480: 6 cells cut aerial_grid's bridges over
#: its holes (mesh F@0.2 % .752 -> .667).
MAX_EDGE_CELLS = 16.0
#: a view agrees with a point where its depth map holds the point's depth within this (relative; fusion's
#: max_depth_error)
AGREE = 0.01


def _facets(points: np.ndarray, simplices: np.ndarray, tet: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The corners (F, 3) of facet ``k`` of each tetrahedron ``tet``, ordered so that the facet's normal
    points away from the tetrahedron."""
    faces = simplices[tet[:, None], _OTHERS[k]]
    n = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    flip = ((points[simplices[tet, k]] - points[faces[:, 0]]) * n).sum(1) > 0
    faces[flip] = faces[flip][:, ::-1]
    return faces


def _seen_from_outside(points, faces, ray_point, ray_view, centres) -> np.ndarray:
    """Per hull facet of an inside tetrahedron (``faces``, turned outwards): whether each of its corners
    is seen by a view on the facet's outer side. The outside of the hull is free space, so such facets
    bound the surface too (an object's convex side); those no view faces are the hull's underside, below
    a terrain or behind a facade, where no view looked."""
    if len(faces) == 0:
        return np.zeros(0, bool)
    used, corners = np.unique(faces, return_inverse=True)  # (only the hull's points: a small share)
    corners = corners.reshape(-1, 3)
    ray = np.isin(ray_point, used)
    seen = np.zeros((len(used), len(centres)), bool)
    seen[np.searchsorted(used, ray_point[ray]), ray_view[ray]] = True
    p = points[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    facing = ((centres[None] - p[:, :1]) * normal[:, None]).sum(2) > 0
    return np.all([(seen[corners[:, j]] & facing).any(axis=1) for j in range(3)], axis=0)


def delaunay_mesh(points: np.ndarray, colors: np.ndarray | None, views: Iterable[tuple[ViewCamera, np.ndarray]],
                  options: MeshOptions = MeshOptions()) -> trimesh.Trimesh:
    """The graph-cut Delaunay surface of ``points`` (N, 3), thinned to one per cell of the points' robust
    extent / 2^(``options.depth`` + 1), from the lines of sight of the ``views`` (camera, depth map) that
    agree with them; vertex colours (uint8) from ``colors`` (N x 3). Raises ValueError where the points
    do not span a volume."""
    import maxflow

    start = time.perf_counter()
    points = np.asarray(points, np.float64)
    cell = robust_extent(points) / 2 ** (options.depth + 1)
    keep = thin(points, cell)
    points = points[keep]
    colors = None if colors is None else np.asarray(colors, np.uint8)[keep]
    ray_point, ray_view, centres = lines_of_sight(points, views, AGREE)
    try:
        tri = Delaunay(points)
    except QhullError as e:
        raise ValueError(f"the {len(points)} points do not span a volume (Qhull: {str(e).splitlines()[0]})") from e
    simplices = tri.simplices.astype(np.int64)
    neighbors = tri.neighbors.astype(np.int64)
    log.info("delaunay: %d points (one per cell of %.3g), %d lines of sight, %d tetrahedra (%.1f s)",
             len(points), cell, len(ray_point), len(simplices), time.perf_counter() - start)
    vertex_tet = np.zeros(len(points), np.int64)
    vertex_tet[simplices.ravel()] = np.repeat(np.arange(len(simplices)), 4)
    step = np.maximum(0.5 * cKDTree(points).query(points, k=2)[0][:, 1], 1e-9 * cell)
    facet_in = np.zeros((len(simplices), 4))
    source = np.zeros(len(simplices))
    sink = np.zeros(len(simplices))
    _cast(points, centres, ray_point, ray_view, vertex_tet, np.ascontiguousarray(tri.transform), neighbors,
          step, 1.0, facet_in, source, sink)
    quality = _facet_quality(tri)
    tet, k = np.nonzero(neighbors >= 0)
    other = neighbors[tet, k]
    back = np.argmax(neighbors[other] == tet[:, None], axis=1)  # the facet's index seen from the other side
    graph = maxflow.Graph[float]()
    nodes = graph.add_nodes(len(simplices))
    graph.add_edges(nodes[other], nodes[tet],
                    facet_in[tet, k] + QUALITY_WEIGHT * np.maximum(quality[tet, k], quality[other, back]),
                    np.zeros(len(tet)))
    graph.add_grid_tedges(nodes, source, sink)
    graph.maxflow()
    inside = graph.get_grid_segments(nodes)  # True: on the sink's side
    surface = inside[tet] & ~inside[other]
    hull_t, hull_k = np.nonzero((neighbors < 0) & inside[:, None])
    hull = _facets(points, simplices, hull_t, hull_k)
    # each face turned away from its inside tetrahedron, towards the free side
    faces = np.concatenate([_facets(points, simplices, tet[surface], k[surface]),
                            hull[_seen_from_outside(points, hull, ray_point, ray_view, centres)]])
    corners = points[faces]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    short = longest <= MAX_EDGE_CELLS * cell
    faces = faces[short]
    out = trimesh.Trimesh(points, faces, process=False)
    if colors is not None:
        out.visual.vertex_colors = colors
    out.remove_unreferenced_vertices()
    log.info("delaunay: %d of %d tetrahedra inside, %d faces (%d longer than %g cells dropped) in %.1f s",
             int(inside.sum()), len(simplices), len(out.faces), int((~short).sum()),
             MAX_EDGE_CELLS, time.perf_counter() - start)
    return out
