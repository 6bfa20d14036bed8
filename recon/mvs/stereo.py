"""Per-view drivers of the CPU PatchMatch stereo on a COLMAP undistorted workspace.

``dense_dir`` is the folder ``pycolmap.undistort_images`` writes (``images/``, ``sparse/`` with
PINHOLE cameras, ``stereo/``). Maps are written in COLMAP's layout under ``out_dir`` (normally
``dense_dir/stereo``)::

    depth_maps/<image>.photometric.bin    normal_maps/<image>.photometric.bin
    depth_maps/<image>.geometric.bin      normal_maps/<image>.geometric.bin
    source_masks/<image>.photometric.npz  (recon's own: each pixel's sources, for the geometric pass)

at the working resolution (longest side at most ``max_image_size``), which fusion (recon's, or
``pycolmap.stereo_fusion``) reads with the full-size images. Each file is written atomically and the
depth map last, so a depth map on disk means the view is complete. Filtered pixels have depth 0 and
normal (0, 0, 0).

Depth at pixel (col, row) is along the ray through (col + 0.5, row + 0.5), recon's and COLMAP's
sparse convention, and recon's fusion (recon.mvs.fusion) reads it so; COLMAP's own fusion back-projects
it through (col, row), half a working-resolution pixel aside.
"""

from __future__ import annotations

import functools
import logging
import time
import zlib
from pathlib import Path

import cv2
import numba
import numpy as np
import pycolmap

from recon.files import atomic
from recon.mvs import patchmatch
from recon.mvs.at_infinity import drop_at_infinity
from recon.mvs.background import clear_background
from recon.mvs.colmap_io import read_depth_map, read_normal_map, write_map
from recon.mvs.fattening import drop_fattened
from recon.mvs.options import MVSOptions
from recon.mvs.planar_fill import fill_untextured
from recon.mvs.views import Problem, ViewCamera, select_problems
from recon.products import SparseModel

log = logging.getLogger(__name__)


def map_path(out_dir: str | Path, kind: str, name: str, pass_name: str) -> Path:
    """``out_dir/{kind}_maps/<name>.<pass_name>.bin`` for kind 'depth' or 'normal', pass
    'photometric' or 'geometric'."""
    return Path(out_dir) / f"{kind}_maps" / f"{name}.{pass_name}.bin"


#: the folder, beside depth_maps/ and normal_maps/, of the photometric pass's per-pixel source masks
SOURCE_MASKS = "source_masks"


def sources_path(out_dir: str | Path, name: str) -> Path:
    """``out_dir/source_masks/<name>.photometric.npz``: the photometric pass's per-pixel source masks."""
    return Path(out_dir) / SOURCE_MASKS / f"{name}.photometric.npz"


def write_source_masks(path: Path, views: np.ndarray, sources: list[str]) -> None:
    """Each pixel's bit mask of the sources it was matched against (bit i: ``sources[i]``), atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, views=views.astype(np.uint32), sources=np.array(sources))


def read_source_masks(path: Path, sources: list[str]) -> np.ndarray | None:
    """The masks :func:`write_source_masks` left at ``path`` (int64, as :class:`patchmatch.State` holds
    them) when they index exactly ``sources``; None when there are none or they index other sources."""
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as data:
        if data["sources"].tolist() != list(sources):
            return None
        return data["views"].astype(np.int64)


@functools.lru_cache(maxsize=32)
def _decoded_grey(path: str, version: tuple[int, int], size: tuple[int, int]) -> tuple[tuple[int, int], np.ndarray]:
    """The image's (height, width) as stored, and its grey pixels resized (area) to ``size``, read-only.

    Kept per process for the 32 latest (path, ``version`` = the file's mtime and size, ``size``): each
    image is a source of several views and both passes read it, so it was decoded again for every view
    that reads it, 17 times per stage on fountain_p11. At the default 1536 px the cache holds at most
    50 MB; a rewritten file has another version, so it is never served stale."""
    image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise FileNotFoundError(f"cannot read image {path}")
    shape = image.shape
    if (shape[1], shape[0]) != size:
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    image.flags.writeable = False
    return shape, image


def load_grey(path: Path, camera: ViewCamera, size: tuple[int, int]) -> tuple[np.ndarray, patchmatch.Camera]:
    """The image as float32 grey in [0, 1] resized (area) to ``size`` = (width, height), and its camera."""
    try:
        stat = path.stat()
    except OSError:
        raise FileNotFoundError(f"cannot read image {path}") from None
    shape, image = _decoded_grey(str(path), (stat.st_mtime_ns, stat.st_size), tuple(size))
    if shape != (camera.height, camera.width):
        raise ValueError(f"{path}: image is {shape[1]}x{shape[0]}, its camera {camera.width}x{camera.height}")
    cam = patchmatch.Camera(camera.K, camera.R, camera.t).scaled(size[0] / camera.width,
                                                                   size[1] / camera.height)
    return image.astype(np.float32) / 255.0, cam


def working_size(camera: ViewCamera, max_image_size: int) -> tuple[int, int]:
    """(width, height) of the depth map of an image: its size, scaled down to fit max_image_size."""
    scale = min(1.0, max_image_size / max(camera.width, camera.height))
    return max(1, round(camera.width * scale)), max(1, round(camera.height * scale))


def _seed(options: MVSOptions, name: str) -> int:
    return (options.seed * 1_000_003 + zlib.crc32(name.encode())) & 0x7FFFFFFF


def _use_threads(options: MVSOptions) -> None:
    available = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(min(options.num_threads, available) if options.num_threads else available)


def photometric_view(dense_dir: str | Path, problem: Problem, options: MVSOptions,
                     out_dir: str | Path) -> Path:
    """Photometric depth and normal maps of ``problem.ref``; returns the depth map's path."""
    _use_threads(options)
    start = time.perf_counter()
    images = Path(dense_dir) / "images"
    views = [problem.cameras[name] for name in (problem.ref, *problem.sources)]
    loaded = [load_grey(images / v.name, v, working_size(v, options.max_image_size)) for v in views]
    state = patchmatch.photometric_depth(
        loaded[0][0], [im for im, _ in loaded[1:]], loaded[0][1], [cam for _, cam in loaded[1:]],
        (problem.depth_min, problem.depth_max), options, _seed(options, problem.ref),
        None if problem.ground is None else np.asarray(problem.ground))
    write_source_masks(sources_path(out_dir, problem.ref), state.views, list(problem.sources))
    write_map(map_path(out_dir, "normal", problem.ref, "photometric"), state.normal)
    path = write_map(map_path(out_dir, "depth", problem.ref, "photometric"), state.depth)
    log.info("%s: photometric depth %dx%d in %.1f s", problem.ref, state.depth.shape[1],
             state.depth.shape[0], time.perf_counter() - start)
    return path


def geometric_view(dense_dir: str | Path, problem: Problem, options: MVSOptions,
                   out_dir: str | Path) -> Path:
    """Geometric-consistency refinement (when ``options.geometric``) and filtering of the photometric
    maps of ``problem.ref`` against its sources' photometric depth maps; returns the depth map's path.

    Needs the reference's photometric maps in ``out_dir``; sources without a photometric depth map
    (images that got no problem of their own) are left out. In the geometric pass each pixel starts with
    the sources the photometric pass chose for it when its source masks index these sources; otherwise
    it chooses again among all.
    """
    _use_threads(options)
    start = time.perf_counter()
    images = Path(dense_dir) / "images"
    depth = read_depth_map(map_path(out_dir, "depth", problem.ref, "photometric"))
    normal = read_normal_map(map_path(out_dir, "normal", problem.ref, "photometric"))
    sources = [name for name in problem.sources if map_path(out_dir, "depth", name, "photometric").exists()]
    if len(sources) < len(problem.sources):
        log.warning("%s: no photometric depth map for sources %s", problem.ref,
                    sorted(set(problem.sources) - set(sources)))
    if sources:
        src_depths = [read_depth_map(map_path(out_dir, "depth", name, "photometric")) for name in sources]
        ref, ref_cam = load_grey(images / problem.ref, problem.cameras[problem.ref], depth.shape[::-1])
        srcs, src_cams = [], []
        for name, src_depth in zip(sources, src_depths):
            image, cam = load_grey(images / name, problem.cameras[name], src_depth.shape[::-1])
            srcs.append(image)
            src_cams.append(cam)
        geometric = options.geometric and options.geometric_iterations > 0
        masks = read_source_masks(sources_path(out_dir, problem.ref), sources) if geometric else None
        views = np.full(depth.shape, (1 << len(sources)) - 1, np.int64) if masks is None else masks
        state = patchmatch.State(depth, normal, np.zeros_like(depth), views)
        view = patchmatch.checked(ref, srcs, ref_cam, src_cams, src_depths)
        if geometric:
            state = patchmatch.geometric_depth(view, state, (problem.depth_min, problem.depth_max), options,
                                               _seed(options, problem.ref), keep_views=masks is not None)
        else:
            state = patchmatch.photometric_costs(view, state, options)
        fill = options.planar_fill and options.min_texture > 0
        clear = options.clear_background and options.min_texture > 0
        blank = patchmatch.untextured(view.level.ref, options) if fill or clear else None
        state = patchmatch.filter_depth(view, state, options, blank)
        if options.drop_at_infinity:
            dropped = drop_at_infinity(view, state, options)
            log.debug("%s: %d pixels matched no better at infinity lost their depth", problem.ref, dropped)
        depth, normal = state.depth, state.normal
        if options.drop_fattened:
            dropped = drop_fattened(ref, ref_cam, depth, normal, srcs, src_cams, src_depths, options)
            log.debug("%s: %d pixels beside a silhouette lost the foreground's depth", problem.ref, dropped)
        if clear:
            cleared = clear_background(view.level.ref, blank, depth, normal, options)
            log.debug("%s: %d pixels beside the sky or a backdrop, of its shade, lost their depth", problem.ref,
                      cleared)
        if fill:
            filled = fill_untextured(view.level.ref, blank, depth, normal, view.level.geometry.kinv,
                                     options.filter_max_depth_error)
            log.debug("%s: %d pixels of untextured regions filled with their rim's plane", problem.ref, filled)
    else:
        depth, normal = np.zeros_like(depth), np.zeros_like(normal)
    write_map(map_path(out_dir, "normal", problem.ref, "geometric"), normal)
    path = write_map(map_path(out_dir, "depth", problem.ref, "geometric"), depth)
    log.info("%s: geometric depth in %.1f s, %.0f%% of pixels kept", problem.ref,
             time.perf_counter() - start, 100.0 * np.count_nonzero(depth) / depth.size)
    return path


def dense_stereo(dense_dir: str | Path, options: MVSOptions = MVSOptions(),
                 out_dir: str | Path | None = None) -> list[Path]:
    """Depth maps of every image of an undistorted workspace, in one process: both passes for all
    views, skipping views whose maps already exist. Returns the geometric depth maps' paths."""
    dense_dir = Path(dense_dir)
    out_dir = Path(out_dir) if out_dir is not None else dense_dir / "stereo"
    problems = select_problems(pycolmap.Reconstruction(dense_dir / SparseModel.MODELS), options)
    for problem in problems:
        if not map_path(out_dir, "depth", problem.ref, "photometric").exists():
            photometric_view(dense_dir, problem, options, out_dir)
    paths = []
    for problem in problems:
        path = map_path(out_dir, "depth", problem.ref, "geometric")
        paths.append(path if path.exists() else geometric_view(dense_dir, problem, options, out_dir))
    return paths


def mask_maps(out_dir: str | Path, name: str, mask: np.ndarray, pass_name: str) -> int:
    """Clear the depth and normal of every masked pixel (``mask`` False, at any resolution) in the maps of
    ``name``: a pixel that is not the subject gives no depth, so no fused point, face or texel.
    Idempotent (a resumed run may apply it again); returns how many depths it cleared."""
    from recon.imaging.masks import mask_at
    from recon.mvs.colmap_io import read_map, write_map

    depth_path = map_path(out_dir, "depth", name, pass_name)
    depth = read_map(depth_path)
    off = ~mask_at(mask, depth.shape[1], depth.shape[0])
    cleared = int(np.count_nonzero(depth[off]))
    if cleared:
        depth[off] = 0
        write_map(depth_path, depth)
        normal_path = map_path(out_dir, "normal", name, pass_name)
        if normal_path.exists():
            normal = read_map(normal_path)
            normal[off] = 0
            write_map(normal_path, normal)
    return cleared
