"""Surface accuracy, completeness and F-score of a reconstruction against a synthetic scene.

Thresholds are fractions of the scene's ``extent`` (see recon.synth.dataset: the diagonal of the
bounding box of the surface the regular views see); results are percentages.

- Accuracy@tau: share of reconstructed points (or of uniform samples of a reconstructed mesh, about
  three per threshold length) whose distance to the ground-truth mesh is <= tau (exact point-to-
  triangle distance, open3d ``RaycastingScene.compute_distance``).
- Completeness@tau: share of the OBSERVABLE ground-truth surface within tau of the reconstruction.
  The observable surface is the union of the points back-projected from the ground-truth depth maps
  of the regular (input) views, thinned to one point per voxel of half the smallest threshold, so
  every area counts alike and ground no camera sees does not count. Distance to a reconstructed mesh
  is exact; to a point cloud it is the nearest-point distance (scipy cKDTree), searched only up to
  the largest threshold (farther counts as infinite, so ``completeness_median`` is inf when more
  than half of the observable surface is farther than that).
- F-score@tau: harmonic mean of the two (0 when both are 0).
"""

from __future__ import annotations

import functools
import logging
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from recon._open3d import open3d
from recon.surface.raycast import scene_of
from recon.synth.dataset import SceneInfo

log = logging.getLogger(__name__)

THRESHOLDS = (0.002, 0.005)
MAX_MESH_SAMPLES = 3_000_000


def surface_metrics(points_or_mesh, scene: SceneInfo, thresholds=THRESHOLDS, seed: int = 0) -> dict:
    """Accuracy, completeness and F-score (percent) of a reconstruction against ``scene``.

    ``points_or_mesh``: an (N, 3) array, a trimesh mesh or point cloud, an open3d (legacy or tensor)
    point cloud or triangle mesh, or the path of a ``.ply``/``.obj``/... file. Keys: ``accuracy@tau``,
    ``completeness@tau``, ``fscore@tau`` and ``threshold@tau`` (absolute) for each ``tau``, plus
    ``accuracy_median`` / ``completeness_median`` (absolute distances), ``n_points``, ``n_gt_samples``
    and ``extent``.
    """
    start = time.perf_counter()
    thresholds = tuple(float(t) for t in thresholds)
    extent = scene.extent
    spacing = min(thresholds) * extent / 2
    verts, faces = _as_geometry(points_or_mesh)
    points = verts if faces is None else sample_mesh(verts, faces, spacing * 2 / 3, seed)

    acc_dist = ground_truth_distance(scene)(points)
    gt_pts = observed_points(scene, spacing)
    if faces is None:
        # bounded: unbounded nearest-neighbour queries far from a thin (planar) cloud take minutes
        bound = max(thresholds) * extent
        comp_dist = cKDTree(points).query(gt_pts, workers=-1, distance_upper_bound=bound)[0] \
            if len(points) else np.full(len(gt_pts), np.inf)
    else:
        comp_dist = _mesh_distance(verts, faces)(gt_pts)

    out = {"extent": extent, "n_points": len(points), "n_gt_samples": len(gt_pts),
           "accuracy_median": float(np.median(acc_dist)) if len(acc_dist) else float("inf"),
           "completeness_median": float(np.median(comp_dist))}
    for tau in thresholds:
        limit = tau * extent
        acc = 100.0 * float(np.mean(acc_dist <= limit)) if len(acc_dist) else 0.0
        comp = 100.0 * float(np.mean(comp_dist <= limit))
        out[f"threshold@{tau:g}"] = limit
        out[f"accuracy@{tau:g}"] = acc
        out[f"completeness@{tau:g}"] = comp
        out[f"fscore@{tau:g}"] = 2 * acc * comp / (acc + comp) if acc + comp > 0 else 0.0
    log.info("surface metrics of %d points vs %d ground-truth samples in %.2f s", len(points), len(gt_pts),
             time.perf_counter() - start)
    return out


def observed_points(scene: SceneInfo, spacing: float) -> np.ndarray:
    """The observable ground-truth surface: points back-projected from the regular views' depth maps,
    one per voxel of side ``spacing`` (M, 3). Cached per scene and spacing."""
    stamp = scene.cameras_path.stat().st_mtime_ns
    return _observed_points(str(scene.root), float(spacing), stamp)


@functools.lru_cache(maxsize=4)
def _observed_points(root: str, spacing: float, _stamp: int) -> np.ndarray:
    from recon.synth.dataset import load_scene
    from recon.synth.wide import load_views, range_points

    scene = load_scene(root)
    wide = load_views(root)  # fisheye / 360 views: their maps hold ranges along COLMAP's rays
    chunks = []
    for name, cam in scene.cameras().items():
        depth = scene.depth(name)
        if name in wide:
            chunks.append(range_points(depth, wide[name]))
            continue
        v, u = np.nonzero(depth > 0)
        chunks.append(cam.backproject(np.column_stack([u + 0.5, v + 0.5]), depth[v, u]))
    pts = np.concatenate(chunks)
    keys = np.floor(pts / spacing).astype(np.int64)  # voxel grid anchored at the world origin
    keys -= keys.min(0)
    dims = keys.max(0) + 1
    flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    _, first = np.unique(flat, return_index=True)
    return pts[first]


def views_seeing(scene: SceneInfo, points: np.ndarray, tolerance: float = 0.01) -> np.ndarray:
    """How many of ``scene``'s regular views see each of ``points`` (N, 3): the point projects into the
    view, and a true depth at its pixel or one of the 8 around it is the point's own within ``tolerance``
    (relative). The neighbours count so that a surface seen at a grazing angle, whose depth changes fast
    from pixel to pixel, is not missed: the count errs high (near an occluding edge a view that does not
    see the point can count), so a share of the surface it gives is an upper bound. Pinhole views only (a
    fisheye or 360 view's map holds ranges: ValueError)."""
    from recon.synth.wide import load_views

    if load_views(scene.root):
        raise ValueError(f"{scene.root}: views_seeing counts pinhole views only")
    count = np.zeros(len(points), np.int32)
    for name, cam in scene.cameras().items():
        truth = scene.depth(name)
        height, width = truth.shape
        uv, z = cam.project(points)
        front = np.flatnonzero(z > 0)
        u = np.floor(uv[front, 0]).astype(np.int64)
        v = np.floor(uv[front, 1]).astype(np.int64)
        inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
        front, u, v = front[inside], u[inside], v[inside]
        seen = np.zeros(len(front), bool)
        for dv in (-1, 0, 1):
            for du in (-1, 0, 1):
                d = truth[np.clip(v + dv, 0, height - 1), np.clip(u + du, 0, width - 1)]
                seen |= np.abs(d - z[front]) <= tolerance * z[front]
        count[front[seen]] += 1
    return count


def sample_mesh(vertices: np.ndarray, faces: np.ndarray, spacing: float, seed: int = 0) -> np.ndarray:
    """Points spread uniformly over a triangle mesh's area, about one per ``spacing``^2 (between
    1000 and MAX_MESH_SAMPLES)."""
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = area.sum()
    if total <= 0:
        return np.zeros((0, 3))
    n = int(np.clip(total / spacing**2, 1000, MAX_MESH_SAMPLES))
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(tri), size=n, p=area / total)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    w = np.column_stack([1 - s, s * (1 - r2), s * r2])
    return np.einsum("nk,nkd->nd", w, tri[idx])


def _mesh_distance(vertices: np.ndarray, faces: np.ndarray):
    o3d = open3d()
    rc = scene_of(vertices, faces)

    def distance(points: np.ndarray) -> np.ndarray:
        if len(points) == 0:
            return np.zeros(0)
        return rc.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy().astype(np.float64)

    return distance


def ground_truth_distance(scene: SceneInfo):
    """A function giving the distance of (N, 3) points to ``scene``'s true mesh (exact; cached per scene)."""
    return _gt_distance(str(scene.mesh_path), scene.mesh_path.stat().st_mtime_ns)


@functools.lru_cache(maxsize=4)
def _gt_distance(mesh_path: str, _stamp: int):
    mesh = _gt_mesh(mesh_path, _stamp)
    return _mesh_distance(mesh.vertices, mesh.faces)


@functools.lru_cache(maxsize=4)
def _gt_mesh(mesh_path: str, _stamp: int):
    import trimesh

    return trimesh.load(mesh_path, process=False, force="mesh")


def normal_angles(vertices: np.ndarray, faces: np.ndarray, scene: SceneInfo, limit: float, samples: int = 20_000,
                  seed: int = 0) -> np.ndarray:
    """Angles (degrees, 0-90) between the faces of a mesh (in the scene's frame) and the true surface: for up
    to ``samples`` faces, drawn at random, whose centroid lies within ``limit`` of the true mesh, the angle of
    the face's normal to the normal of the nearest true triangle, sign aside. A flat face that comes out
    bumpy, or an edge rounded off, shows here while the F-scores, which count distance alone, barely move."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    picked = np.random.default_rng(seed).choice(len(faces), min(samples, len(faces)), replace=False)
    corners = vertices[faces[picked]]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1)
    corners, normals = corners[length > 0], normals[length > 0] / length[length > 0, None]
    truth = _gt_mesh(str(scene.mesh_path), scene.mesh_path.stat().st_mtime_ns)
    centroids = corners.mean(axis=1)
    nearest = scene_of(truth.vertices, truth.faces).compute_closest_points(
        open3d().core.Tensor(centroids.astype(np.float32)))
    on = np.linalg.norm(nearest["points"].numpy() - centroids, axis=1) <= limit
    true_normals = np.asarray(truth.face_normals)[nearest["primitive_ids"].numpy().astype(np.int64)[on]]
    cos = np.abs(np.einsum("ij,ij->i", normals[on], true_normals))
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


def _as_geometry(obj) -> tuple[np.ndarray, np.ndarray | None]:
    """(vertices, faces or None) of any supported point cloud / mesh input."""
    if isinstance(obj, (str, Path)):
        import trimesh

        obj = trimesh.load(str(obj), process=False)
    if isinstance(obj, np.ndarray):
        return np.asarray(obj, dtype=float).reshape(-1, 3), None
    cls = type(obj).__module__ + "." + type(obj).__name__
    if cls.startswith("trimesh"):
        faces = getattr(obj, "faces", None)
        if faces is not None and len(faces):
            return np.asarray(obj.vertices, float), np.asarray(faces)
        return np.asarray(obj.vertices, float), None
    if cls.startswith("open3d"):
        if hasattr(obj, "to_legacy"):
            obj = obj.to_legacy()
        if hasattr(obj, "triangles") and len(obj.triangles):
            return np.asarray(obj.vertices, float), np.asarray(obj.triangles)
        if hasattr(obj, "points"):
            return np.asarray(obj.points, float), None
        return np.asarray(obj.vertices, float), None
    raise TypeError(f"cannot evaluate a {type(obj).__name__}: give points (N, 3), a mesh or a file path")


def object_metrics(mesh, object_mesh, thresholds=THRESHOLDS, seed: int = 0, extent: float | None = None,
                   observable=None) -> dict:
    """Accuracy, completeness and F-score (percent) of a mesh or a point cloud (any input of
    :func:`surface_metrics`) against one object alone (a masked capture's subject), at each ``tau``
    times ``extent`` (default: the object's bounding-box diagonal): accuracy over samples of ``mesh``
    (or its points; anything else it holds counts against it), completeness over samples of the
    object's surface. Given ``observable`` (a function of (N, 3) points giving True where a view sees
    them, as :func:`views_seeing` tells), only those samples count, as :func:`surface_metrics` counts
    the observable surface alone: an object standing on a table has an underside no photo sees (the
    zoo's masked_object: 10 % of its surface), which no reconstruction can hold. Without it, the
    whole surface counts."""
    verts, faces = _as_geometry(mesh)
    obj_verts, obj_faces = _as_geometry(object_mesh)
    extent = extent or float(np.linalg.norm(np.ptp(obj_verts, axis=0)))
    spacing = min(float(t) for t in thresholds) * extent / 2
    points = verts if faces is None else sample_mesh(verts, faces, spacing, seed)
    truth = sample_mesh(obj_verts, obj_faces, spacing, seed + 1)
    if observable is not None:
        truth = truth[observable(truth)]
    acc = _mesh_distance(obj_verts, obj_faces)(points)
    if faces is None:
        bound = max(thresholds) * extent
        comp = cKDTree(points).query(truth, workers=-1, distance_upper_bound=bound)[0] if len(points) \
            else np.full(len(truth), np.inf)
    else:
        comp = _mesh_distance(verts, faces)(truth)
    out = {}
    for tau in thresholds:
        a, c = 100 * np.mean(acc <= tau * extent), 100 * np.mean(comp <= tau * extent)
        out.update({f"accuracy@{tau:g}": a, f"completeness@{tau:g}": c,
                    f"fscore@{tau:g}": 2 * a * c / (a + c) if a + c else 0.0})
    return out
