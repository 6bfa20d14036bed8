"""What a report shows, read from a run's files: stage manifests, COLMAP's database and sparse model,
the sfm stage's registration report (``models.json``), dense depth/normal maps, the fused cloud and
the mesh. Everything but the stage manifests may be absent; the report shows what exists."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from recon.geometry.transforms import up_direction
from recon.sparse.database import private_copy
from recon.sparse.residuals import observation_errors

log = logging.getLogger(__name__)


@dataclass
class Sources:
    """The files a report is made from. Paths that are None or do not exist are left out."""

    database: Path | None = None          # COLMAP database.db with keypoints and verified pairs
    model: Path | None = None             # a COLMAP model folder (the largest model, sparse/0)
    models_json: Path | None = None       # the sfm stage's registration report
    georeference: Path | None = None      # the sfm stage's georeference.json (scale and position)
    stages: list[dict] = field(default_factory=list)  # stage manifests, in pipeline order
    run_started: float | None = None      # when the run that makes the report started
    config: dict = field(default_factory=dict)        # the run's resolved config
    stereo: Path | None = None            # COLMAP dense layout: stereo/{depth,normal}_maps/*.bin
    fused: Path | None = None             # fused dense point cloud (.ply)
    mesh: Path | None = None              # mesh.ply
    textured: Path | None = None          # textured.glb


@dataclass
class ImageRow:
    """One photo of the run: how far it got and its figures."""

    name: str
    width: int
    height: int
    keypoints: int
    matched_images: int = 0       # photos sharing geometrically verified matches with it
    verified_matches: int = 0     # inlier matches, summed over those pairs
    registered: bool = False      # part of the largest model
    reason: str = ""              # why it is not registered
    observations: int = 0         # model points it sees
    reproj_error: float | None = None  # mean reprojection error of those observations, pixels


@dataclass
class Model:
    """The largest sparse model, as arrays."""

    names: list[str]
    rotations: np.ndarray      # N x 3 x 3, world to camera
    centers: np.ndarray        # N x 3, camera centres in world coordinates
    intrinsics: np.ndarray     # N x 6: fx, fy, cx, cy, width, height (pinhole part of the camera)
    points: np.ndarray         # M x 3
    colors: np.ndarray         # M x 3 uint8
    track_lengths: np.ndarray  # M
    point_errors: np.ndarray   # per point: its mean reprojection error over the photos that see it, pixels
    mean_error: float          # the mean of point_errors: COLMAP's mean reprojection error, as sfm reports it
    up: np.ndarray             # unit vector: the photos' average "up" in world coordinates


@dataclass
class Matches:
    names: list[str]
    sizes: dict[str, tuple[int, int]]
    keypoints: dict[str, int]
    pairs: np.ndarray          # N x N verified inlier counts, symmetric, in ``names`` order


@dataclass
class DenseView:
    name: str
    depth: np.ndarray | None
    normal: np.ndarray | None


@dataclass
class StageRow:
    name: str
    seconds: float
    finished: float
    ran: bool | None           # ran in the run that made the report (None: unknown)
    summary: dict
    key: str


# ---------------------------------------------------------------------------------------------


def stage_rows(sources: Sources) -> list[StageRow]:
    rows = []
    for m in sources.stages:
        ran = None if sources.run_started is None else m.get("started", 0) >= sources.run_started
        rows.append(StageRow(m["stage"], float(m.get("seconds", 0.0)), float(m.get("finished", 0.0)), ran,
                             m.get("summary", {}), m.get("key", "")))
    return rows


def read_matches(database: Path) -> Matches:
    """Photos, their sizes and keypoint counts, and the verified inlier count of every pair."""
    import pycolmap

    with private_copy(database) as copy:
        db = pycolmap.Database.open(str(copy))
        try:
            cameras = {c.camera_id: c for c in db.read_all_cameras()}
            images = sorted(db.read_all_images(), key=lambda im: im.name)
            names = [im.name for im in images]
            index = {im.image_id: k for k, im in enumerate(images)}
            sizes = {im.name: (cameras[im.camera_id].width, cameras[im.camera_id].height) for im in images}
            keypoints = {im.name: db.num_keypoints_for_image(im.image_id) for im in images}
            pair_ids, inliers = db.read_two_view_geometry_num_inliers()
        finally:
            db.close()
    pairs = np.zeros((len(names), len(names)), dtype=np.int64)
    for pair_id, n in zip(pair_ids, inliers):
        a, b = pycolmap.pair_id_to_image_pair(pair_id)
        if a in index and b in index:
            pairs[index[a], index[b]] = pairs[index[b], index[a]] = n
    return Matches(names, sizes, keypoints, pairs)


def read_model(path: Path) -> tuple[Model, dict[str, tuple[int, float]]]:
    """The model's arrays, and per registered photo (observations, mean reprojection error)."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(path))
    images = sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: im.name)
    point_ids = sorted(rec.points3D)
    xyz = {pid: rec.points3D[pid].xyz for pid in point_ids}
    names, rotations, centers, intrinsics = [], [], [], []
    per_image: dict[str, tuple[int, float]] = {}
    for im in images:
        pose = im.cam_from_world()
        R, t = pose.rotation.matrix(), np.asarray(pose.translation)
        cam = rec.cameras[im.camera_id]
        # a 360 camera has no calibration matrix: its pixels per radian and centre draw its frustum
        K = cam.calibration_matrix() if not cam.is_spherical() else \
            np.array([[cam.width / (2 * np.pi), 0, cam.width / 2], [0, cam.height / np.pi, cam.height / 2], [0, 0, 1]])
        names.append(im.name)
        rotations.append(R)
        centers.append(-R.T @ t)
        intrinsics.append([K[0, 0], K[1, 1], K[0, 2], K[1, 2], cam.width, cam.height])
        errors = observation_errors(rec, im)
        per_image[im.name] = (len(errors), float(errors.mean()) if len(errors) else float("nan"))
    rotations_a = np.array(rotations).reshape(-1, 3, 3)
    centers_a = np.array(centers).reshape(-1, 3)
    model = Model(
        names=names, rotations=rotations_a, centers=centers_a,
        intrinsics=np.array(intrinsics, dtype=float).reshape(-1, 6),
        points=np.array([xyz[p] for p in point_ids], dtype=float).reshape(-1, 3),
        colors=np.array([rec.points3D[p].color for p in point_ids], dtype=np.uint8).reshape(-1, 3),
        track_lengths=np.array([rec.points3D[p].track.length() for p in point_ids], dtype=int),
        point_errors=np.array([rec.points3D[p].error for p in point_ids if rec.points3D[p].has_error()], float),
        mean_error=rec.compute_mean_reprojection_error(),
        up=up_direction(rotations_a, centers_a))
    return model, per_image


def image_rows(matches: Matches, registration: dict, per_image: dict[str, tuple[int, float]]) -> list[ImageRow]:
    """One row per photo in the database, with the sfm stage's reason for any photo left out."""
    unregistered = registration.get("unregistered", {})
    rows = []
    for k, name in enumerate(matches.names):
        counts = matches.pairs[k]
        row = ImageRow(name, *matches.sizes[name], keypoints=matches.keypoints[name],
                       matched_images=int((counts > 0).sum()), verified_matches=int(counts.sum()))
        if name in per_image:
            row.registered = True
            row.observations, error = per_image[name]
            row.reproj_error = None if np.isnan(error) else error
        else:
            row.reason = unregistered.get(name) or registration.get("reason") or "not in the largest model"
        rows.append(row)
    return rows


def dense_views(stereo: Path, limit: int) -> tuple[int, list[DenseView]]:
    """How many views have a depth map, and up to ``limit`` of them (evenly spread) read back."""
    from recon.mvs.colmap_io import read_depth_map, read_normal_map

    depth_dir, normal_dir = stereo / "depth_maps", stereo / "normal_maps"
    kind = "geometric" if any(depth_dir.glob("*.geometric.bin")) else "photometric"
    depths = sorted(depth_dir.glob(f"*.{kind}.bin"))
    if not depths:
        return 0, []
    picks = sorted({int(round(i)) for i in np.linspace(0, len(depths) - 1, min(limit, len(depths)))})
    views = []
    for i in picks:
        path = depths[i]
        name = path.name.removesuffix(f".{kind}.bin")
        normal_path = normal_dir / path.name
        views.append(DenseView(name, read_depth_map(path),
                               read_normal_map(normal_path) if normal_path.exists() else None))
    return len(depths), views


def read_point_cloud(path: Path, limit: int, seed: int = 0) -> tuple[int, np.ndarray, np.ndarray]:
    """(total points, up to ``limit`` points chosen at random, their colours as uint8)."""
    import trimesh

    cloud = trimesh.load(path, process=False)
    xyz = np.asarray(cloud.vertices, dtype=float)
    colors = getattr(cloud, "colors", None)
    rgb = np.asarray(colors)[:, :3].astype(np.uint8) if colors is not None and len(colors) == len(xyz) \
        else np.full((len(xyz), 3), 200, np.uint8)
    keep = np.sort(np.random.default_rng(seed).choice(len(xyz), limit, replace=False)) if len(xyz) > limit \
        else np.arange(len(xyz))
    return len(xyz), xyz[keep], rgb[keep]


def mesh_statistics(path: Path) -> dict:
    """Counts and shape figures of a triangle mesh, for the report's table."""
    import trimesh

    mesh = trimesh.load(path, process=False, force="mesh")
    components = trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)),
                                                    min_len=1)
    edges = mesh.edges_sorted
    _, counts = np.unique(edges, axis=0, return_counts=True) if len(edges) else (None, np.zeros(0))
    extent = mesh.bounds[1] - mesh.bounds[0] if len(mesh.vertices) else np.zeros(3)
    return {
        "vertices": int(len(mesh.vertices)),
        "faces": int(len(mesh.faces)),
        "components": int(len(components)),
        "surface area": float(mesh.area),
        "bounding box": " x ".join(f"{v:.3g}" for v in extent),
        "watertight": bool(mesh.is_watertight),
        "boundary edges": int((counts == 1).sum()),
        "non-manifold edges": int((counts > 2).sum()),
        "vertex colours": bool(mesh.visual.kind == "vertex"),
    }
