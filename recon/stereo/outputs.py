"""What two-view stereo writes: the depth map (float .npy, COLMAP .bin, colour-mapped preview) and a
coloured point cloud (binary PLY)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.geometry.transforms import apply_matrix
from recon.stereo.depth import StereoDepth


def point_cloud(result: StereoDepth, pose: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """(points (N, 3) float64, colours (N, 3) uint8) of the pixels with a depth, in the world of the
    left camera's world-to-camera ``pose`` (None: the left camera's frame)."""
    rows, cols = np.nonzero(result.depth > 0)
    rays = result.camera.undistort_pixels(np.column_stack([cols + 0.5, rows + 0.5]))
    z = result.depth[rows, cols].astype(np.float64)[:, None]
    points = np.column_stack([rays, np.ones(len(rays))]) * z
    if pose is not None:
        R, t = (np.asarray(v, dtype=np.float64) for v in pose)
        points = apply_matrix(R.T, points - t)
    image = result.image if result.image.ndim == 3 else np.repeat(result.image[..., None], 3, axis=2)
    return points, image[rows, cols].astype(np.uint8)


def write_ply(path: str | Path, points: np.ndarray, colours: np.ndarray) -> Path:
    """A binary PLY point cloud with RGB colours (MeshLab, CloudCompare, trimesh, open3d read it)."""
    import trimesh

    cloud = trimesh.PointCloud(points, colors=np.column_stack([colours, np.full(len(colours), 255, np.uint8)]))
    path = Path(path)
    path.write_bytes(cloud.export(file_type="ply"))
    return path


def write_depth(folder: str | Path, depth: np.ndarray) -> dict[str, Path]:
    """``depth.npy`` (float32 camera z, 0 = none), ``depth.bin`` (COLMAP's depth-map format, what
    recon's dense stage writes) and ``depth_preview.png`` (near to far in turbo colours, black = none)
    in ``folder``; returns their paths by kind."""
    from recon.mvs.colmap_io import write_map
    from recon.report.plots import depth_thumbnail

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {"npy": folder / "depth.npy", "bin": folder / "depth.bin", "preview": folder / "depth_preview.png"}
    np.save(paths["npy"], depth.astype(np.float32))
    write_map(paths["bin"], depth)
    paths["preview"].write_bytes(depth_thumbnail(depth, width=depth.shape[1]))
    return paths
