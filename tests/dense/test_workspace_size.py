"""A lean workspace: intermediates no later stage reads are dropped when their stage completes
(mvs's photometric maps and source masks, COLMAP's fused.ply.vis), the cache still checks out, and
options keep them.

Sizes count each file once (the item store hard-links the maps it keeps) and leave the photos out
(ingest links them). A lean workspace's depth and normal maps take at most 26 bytes per working
pixel: the final depth (4) and normal (12) maps, and the photometric depth (4) and normals (float16,
6) the item store keeps for later runs; keeping the photometric maps in mvs's output makes it 32 there.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from PIL import Image

import recon
import recon.api
from recon.pipeline import status

REPO = Path(__file__).resolve().parents[2]
FULL = REPO / "pipelines" / "full.yaml"
SIZE = 240  # undistorted images and depth maps at most this many px
QUICK = ["executor=serial", "sfm.deterministic=true", f"undistort.max_image_size={SIZE}",
         f"mvs.max_image_size={SIZE}", "mvs.pyramid_levels=2", "mvs.iterations=3", "mesh.depth=8",
         "mesh.target_faces=40000", "texture.max_faces=20000"]
LEAN_MAP_BYTES = 4 + 12 + 4 + 6  # per working pixel: final depth and normal; photometric depth and normals in the store
KEPT_OUTPUT_BYTES = 2 * (4 + 12)  # per working pixel, in mvs's output: final and photometric depth and normal
HEADER = 128  # per map file, at most (COLMAP's "width&height&channels&", NumPy's .npy header)
# 3.5 MiB: SIFT at 800 px in two databases and the item store, sparse model, two fused clouds (the delivered one and
# the one the mesh stage meshes), mesh, texture, report. 16 views at 240 px: 46 MB at session 22 (features 18,
# matching 7, report 6.3, fusion 4.5, texture 4.2); 69 MB at session 46, 3.04 MiB a view besides the maps (maps 18,
# features 18, fusion 9.0: the delivered cloud 6.4 with 236,000 points from 691,000 pixels since fusion merges
# only within merge_px, the mesh's cloud 2.6; matching 7.3, report 6.4, texture 4.4). Keeping the photometric
# maps adds 11 MB, over the budget
OTHER_BYTES_PER_VIEW = 7 * (1 << 20) // 2
MAPS = ("depth_maps", "normal_maps")


def unique_files(root: Path) -> list[Path]:
    """Every regular file under ``root`` once: hard links counted once, symbolic links not followed."""
    found: dict[tuple[int, int], Path] = {}
    for folder, _, names in os.walk(root):
        for name in names:
            path = Path(folder, name)
            st = path.lstat()
            if path.is_file() and not path.is_symlink():
                found.setdefault((st.st_dev, st.st_ino), path)
    return list(found.values())


def size(paths: list[Path]) -> int:
    return sum(p.lstat().st_size for p in paths)


def is_map(path: Path) -> bool:
    """A depth or normal map: in a stage's stereo folder or in the item store."""
    return path.suffix == ".bin" and path.parent.name in MAPS or path.suffix in (".bin", ".npy") and "mvs" in path.parts


def working_pixels(ws: Path) -> int:
    """Pixels of the depth maps of the undistorted images at ``mvs.max_image_size``."""
    total = 0
    for image in (ws / "dense" / "images").iterdir():
        width, height = Image.open(image).size
        scale = min(1.0, SIZE / max(width, height))
        total += round(width * scale) * round(height * scale)
    return total


def config(ws: Path, images: Path, *extra: str):
    return recon.api.load(FULL, [*QUICK, *extra], images=str(images), workspace=str(ws))


@pytest.fixture(scope="module")
def lean(sparse_workspace, small_scene, tmp_path_factory) -> Path:
    """A full run (photos to report) with the default options."""
    ws = tmp_path_factory.mktemp("lean") / "ws"
    shutil.copytree(sparse_workspace, ws, symlinks=True)
    recon.run(FULL, images=str(small_scene / "images"), workspace=str(ws), overrides=QUICK)
    return ws


@pytest.mark.slow
def test_a_full_run_drops_the_intermediates_and_stays_small(lean, small_scene):
    everything = unique_files(lean)
    stereo = lean / "dense" / "stereo"
    views = len(list((lean / "dense" / "images").iterdir()))
    assert len(list((stereo / "depth_maps").glob("*.geometric.bin"))) == views
    assert not list(stereo.glob("*/*.photometric.*")) and not (stereo / "source_masks").exists()
    assert not [p for p in everything if p.name.endswith(".vis") or ".tmp" in p.name]  # COLMAP's fused.ply.vis
    pixels = working_pixels(lean)
    maps = [p for p in everything if is_map(p)]
    assert size(maps) <= LEAN_MAP_BYTES * pixels + HEADER * len(maps)
    assert size(everything) < LEAN_MAP_BYTES * pixels + OTHER_BYTES_PER_VIEW * views
    # the manifests list what exists: with every file re-hashed, the dense stages are done and a run reuses them
    dense = {"undistort", "mvs", "fusion", "mesh", "texture"}
    cfg = config(lean, small_scene / "images")
    assert {s.name: s.state for s in status(cfg, verify=True) if s.name in dense} == dict.fromkeys(dense, "done")
    again = recon.run(FULL, images=str(small_scene / "images"), workspace=str(lean), overrides=QUICK, verify=True)
    assert dense <= set(again.cached)


@pytest.mark.slow
def test_the_keep_options_keep_them(lean, small_scene, tmp_path):
    ws = tmp_path / "ws"
    shutil.copytree(lean, ws, symlinks=True)
    keep = ["mvs.keep_photometric=true", "fusion.keep_visibility=true"]
    recon.run(FULL, images=str(small_scene / "images"), workspace=str(ws), overrides=[*QUICK, *keep],
              until="fusion")
    stereo = ws / "dense" / "stereo"
    names = [p.name.removesuffix(".geometric.bin") for p in (stereo / "depth_maps").glob("*.geometric.bin")]
    assert names and all((stereo / kind / f"{n}.photometric.bin").is_file() for kind in MAPS for n in names)
    assert all((stereo / "source_masks" / f"{n}.photometric.npz").is_file() for n in names)
    assert (ws / "dense" / "fused.ply.vis").stat().st_size > 0
    maps = [p for p in unique_files(stereo.resolve()) if is_map(p)]  # this run's mvs output alone
    assert size(maps) >= KEPT_OUTPUT_BYTES * working_pixels(ws)
