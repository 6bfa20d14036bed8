"""COLMAP's own PatchMatch stereo (CUDA) as an mvs backend: recon's options mapped onto COLMAP's.

Only the options both implementations share are mapped; the rest are recon's CPU kernel's own.
The mapping is one function (:func:`patch_match_options`) so that tests can check it without a GPU.
"""

from __future__ import annotations

from pathlib import Path

from recon.mvs.options import MVSOptions


def cuda_available() -> bool:
    """pycolmap built with CUDA and a GPU it can use (`pip install recon[cuda]`)."""
    try:
        import pycolmap

        devices = getattr(pycolmap, "get_num_cuda_devices", lambda: 1)  # absent in some builds
        return bool(pycolmap.has_cuda) and devices() > 0
    except ImportError:
        return False


def patch_match_options(options: MVSOptions):
    """COLMAP's PatchMatchOptions for recon's MVS options."""
    import pycolmap

    opts = pycolmap.PatchMatchOptions()
    opts.max_image_size = options.max_image_size
    opts.window_radius = options.window_radius
    opts.window_step = options.window_step
    opts.sigma_color = options.sigma_color
    if options.sigma_spatial > 0:
        opts.sigma_spatial = options.sigma_spatial
    opts.min_triangulation_angle = options.min_triangulation_angle
    opts.geom_consistency = options.geometric
    opts.geom_consistency_max_cost = options.geometric_max_error
    opts.filter = True
    opts.filter_min_num_consistent = options.filter_min_consistent
    opts.filter_geom_consistency_max_cost = options.filter_max_reprojection
    if options.num_threads:
        opts.num_threads = options.num_threads
    return opts


def run_patch_match(workspace: Path, options: MVSOptions) -> None:
    """COLMAP's PatchMatch over a COLMAP dense workspace folder (images/, sparse/, stereo/)."""
    import pycolmap

    pycolmap.patch_match_stereo(str(workspace), options=patch_match_options(options))
