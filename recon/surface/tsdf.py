"""Depth-map fusion into a truncated signed distance volume, surface by marching cubes.

Uses open3d's VoxelBlockGrid (hashed 16^3 voxel blocks), so memory follows the surface, not the box.\nThe scene extent (for the default voxel size) is the diagonal of the box holding the middle 99% of the\nback-projected depth-map points.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import trimesh

from recon._open3d import open3d
from recon.geometry.transforms import backproject
from recon.surface.indexing import unique_rows
from recon.surface.options import MeshOptions

log = logging.getLogger(__name__)

_BLOCK_RESOLUTION = 16


def _depth_points(depth: np.ndarray, cam, step: int) -> np.ndarray:
    """World points (N, 3) of every ``step``-th valid (> 0, finite) pixel of a depth map."""
    d = depth[::step, ::step]
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(0, w, step) + 0.5, np.arange(0, h, step) + 0.5)
    ok = np.isfinite(d) & (d > 0)
    return backproject(cam.K, cam.R, cam.t, np.stack([u[ok], v[ok]], axis=1), d[ok])


def tsdf_mesh(depths: Sequence[np.ndarray], images: Sequence[np.ndarray] | None, cameras: Sequence,
              options: MeshOptions = MeshOptions()) -> trimesh.Trimesh:
    """Fuse depth maps (camera z, 0 = none; H x W float) seen by ``cameras`` (objects with K, R, t) into a
    TSDF and extract its zero level set; vertex colours come from ``images`` (H x W x 3 uint8) if given."""
    o3d = open3d()
    core = o3d.core
    pts = np.concatenate([_depth_points(d, c, 4) for d, c in zip(depths, cameras, strict=True)])
    if len(pts) == 0:
        raise ValueError("the depth maps hold no valid depth")
    lo, hi = np.percentile(pts, [0.5, 99.5], axis=0)
    extent = float(np.linalg.norm(hi - lo))
    voxel = options.voxel_size or options.voxel_fraction * extent
    depth_max = options.depth_max_fraction * extent if options.depth_max_fraction > 0 else 1e9
    # the block hash map does not grow on every device: size it from the blocks the points touch
    block = voxel * _BLOCK_RESOLUTION
    cells = np.floor(pts / block).astype(np.int64)
    touched = len(unique_rows(cells - cells.min(axis=0)))
    names, dtypes, channels = ["tsdf", "weight"], [core.float32, core.float32], [1, 1]
    if images is not None:
        names, dtypes, channels = names + ["color"], dtypes + [core.float32], channels + [3]
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=names, attr_dtypes=dtypes, attr_channels=channels, voxel_size=voxel,
        block_resolution=_BLOCK_RESOLUTION, block_count=int(8 * touched + 1000), device=core.Device("CPU:0"))
    for i, (depth, cam) in enumerate(zip(depths, cameras, strict=True)):
        # open3d's integration kernel finds a voxel's pixel by truncating its projection (pixel i spans
        # [i, i + 1)): COLMAP's convention, so K goes in unchanged (a -0.5 shift costs 10x in accuracy)
        K = np.array(cam.K, float)
        extrinsic = np.eye(4)
        extrinsic[:3, :3] = cam.R
        extrinsic[:3, 3] = cam.t
        intrinsic, extrinsic = core.Tensor(K, core.float64), core.Tensor(extrinsic, core.float64)
        d = o3d.t.geometry.Image(core.Tensor(np.where(np.isfinite(depth) & (depth > 0), depth, 0).astype(np.float32)))
        blocks = grid.compute_unique_block_coordinates(d, intrinsic, extrinsic, 1.0, depth_max,
                                                       options.sdf_trunc_voxels)
        if images is None:
            grid.integrate(blocks, d, intrinsic, extrinsic, 1.0, depth_max, options.sdf_trunc_voxels)
        else:
            color = o3d.t.geometry.Image(core.Tensor(np.ascontiguousarray(images[i], np.float32) / 255.0))
            grid.integrate(blocks, d, color, intrinsic, intrinsic, extrinsic, 1.0, depth_max,
                           options.sdf_trunc_voxels)
    mesh = grid.extract_triangle_mesh(weight_threshold=options.min_views)
    out = trimesh.Trimesh(mesh.vertex.positions.numpy().astype(np.float64),
                          mesh.triangle.indices.numpy().astype(np.int64), process=False)
    if images is not None:
        colors = mesh.vertex.colors.numpy()
        out.visual.vertex_colors = np.clip(colors * 255 + 0.5, 0, 255).astype(np.uint8)
    log.info("tsdf voxel %.4g (extent %.4g): %d vertices, %d faces from %d views",
             voxel, extent, len(out.vertices), len(out.faces), len(depths))
    return out
