"""Inputs that break photogrammetry tools: a huge photo, mixed cameras, two scenes in one folder, a
set that cannot be reconstructed, spaces and non-ASCII names. (Empty folders, stray files, corrupt,
0-byte, grey, 16-bit, RGBA, CMYK and EXIF-rotated photos and duplicates: tests/spine/test_ingest.py.)"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
from PIL import Image
from reliability_checks import SPARSE, assert_one_line_error, centres, cli, complete_outputs
from scipy.spatial import cKDTree

from recon.eval.groundtruth import load_cameras
from recon.eval.poses import pose_metrics
from recon.files import read_json


def registered_poses(ws: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Poses of sparse/0 keyed by file name (without folders), as the ground truth names them."""
    rec = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    return {Path(img.name).name: (img.cam_from_world().rotation.matrix(), img.cam_from_world().translation)
            for img in rec.images.values() if img.has_pose}


# ---------------------------------------------------------------------------------------------
# A 12000 px photo

PEAK_RSS = """
import json, resource, sys
from pathlib import Path
from recon.sparse.features import extract_sift
from recon.sparse.features import FeaturesConfig

def peak():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB
settings = FeaturesConfig().settings()
out = {}
for name in sys.argv[1:]:
    keypoints, _ = extract_sift(Path(name), settings)
    out[name] = {"peak_mib": peak(), "keypoints": keypoints[:, :2].tolist()}
print(json.dumps(out))
"""


def test_12000px_photo_is_read_downscaled_in_bounded_memory(tmp_path, small_scene):
    """A 12000 x 9000 JPEG (324 MB as RGB pixels) costs the features worker no more memory than a
    1600 px photo: it is decoded at 1/8 scale (libjpeg) rather than at full size; its keypoints are
    in the photo's own pixel frame."""
    src = cv2.imread(str(small_scene / "images" / "view_000.jpg"))
    normal, huge = tmp_path / "normal.jpg", tmp_path / "huge.jpg"
    cv2.imwrite(str(normal), cv2.resize(src, (1600, 1200), interpolation=cv2.INTER_CUBIC))
    cv2.imwrite(str(huge), cv2.resize(src, (12000, 9000), interpolation=cv2.INTER_CUBIC))
    # the normal photo first: the huge one may only add to the peak what its pixels would cost
    proc = subprocess.run([sys.executable, "-c", PEAK_RSS, str(normal), str(huge)], capture_output=True, text=True,
                          timeout=120, check=True)
    result = json.loads(proc.stdout)
    grown = result[str(huge)]["peak_mib"] - result[str(normal)]["peak_mib"]
    assert grown < 30, f"peak memory grew by {grown:.0f} MiB for the 12000 px photo (its grey pixels: 103 MiB)"
    big = np.array(result[str(huge)]["keypoints"])
    small = np.array(result[str(normal)]["keypoints"])
    assert len(big) > 1000
    assert big.min() >= 0 and big[:, 0].max() <= 12000 and big[:, 1].max() <= 9000
    assert big[:, 0].max() > 11000 and big[:, 1].max() > 8000  # spread over the whole photo
    # the same places as in the 1600 px photo, once scaled by 1600 / 12000
    distance, _ = cKDTree(small).query(big * (1600 / 12000))
    assert np.median(distance) < 1.0


# ---------------------------------------------------------------------------------------------
# Different cameras and sizes in one run


def test_photos_of_different_sizes_and_cameras_reconstruct_together(tmp_path, small_scene):
    """Three cameras over 12 neighbouring views: the originals (320x240, EXIF focal), a higher
    resolution one (400x300) and a longer lens (a central 256x192 crop, no EXIF): one model of all
    12 photos, a camera each, with the right poses."""
    photos = tmp_path / "photos"
    for folder in ("phone", "camera", "zoom"):
        (photos / folder).mkdir(parents=True)
    for i, path in enumerate(sorted((small_scene / "images").glob("*.jpg"))[:12]):
        img = Image.open(path)
        if i % 3 == 0:
            shutil.copy(path, photos / "phone" / path.name)
        elif i % 3 == 1:
            img.resize((400, 300), Image.LANCZOS).save(photos / "camera" / path.name, quality=95, exif=img.getexif())
        else:
            img.crop((32, 24, 288, 216)).save(photos / "zoom" / path.name, quality=95)
    ws = tmp_path / "ws"
    proc = cli("run", SPARSE, "--images", photos, "--workspace", ws)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rec = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    assert rec.num_reg_images() == 12
    assert sorted((c.width, c.height) for c in rec.cameras.values()) == [(256, 192), (320, 240), (400, 300)]
    assert len(read_json(complete_outputs(ws, "sfm")[0] / "models.json")["models"]) == 1
    poses = registered_poses(ws)
    figures = pose_metrics(poses, {k: v for k, v in load_cameras(small_scene).items() if k in poses})
    assert figures["registered"] == 12 and figures["auc@5"] > 80, figures


# ---------------------------------------------------------------------------------------------
# Two scenes in one folder

#: photos (skimage.data) that the synthetic scene's textures do not use
OTHER_PHOTOS = ["astronaut", "rocket", "retina", "hubble_deep_field", "colorwheel", "brick", "moon", "cell", "horse"]


def other_looking_scene(seed: int):
    """The synthetic scene of ``seed`` with every surface covered by other photos: a scene that
    shares no texture with the others (they all share the ground and object photos)."""
    from recon.synth.scene import build_scene
    from recon.synth.textures import fit, make_texture, photo

    base = build_scene(seed)
    parts = []
    for i, part in enumerate(base.parts):
        width, height = part.texture.size
        image = fit(photo(OTHER_PHOTOS[i % len(OTHER_PHOTOS)]), width, height)
        parts.append(dataclasses.replace(part, texture=make_texture(image, wrap=part.texture.wrap)))
    return dataclasses.replace(base, parts=tuple(parts))


@pytest.fixture(scope="module")
def two_scenes(small_scene, tmp_path_factory) -> Path:
    """a/: 8 neighbouring views of the small scene (320x240); b/: another scene (12 views, 400x300)."""
    import recon.synth.dataset as dataset

    root = tmp_path_factory.mktemp("two_scenes")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dataset, "build_scene", other_looking_scene)
        dataset.render_scene(root / "b_scene", views=12, width=400, height=300, seed=2)
    (root / "photos" / "a").mkdir(parents=True)
    for i in range(8):
        shutil.copy(small_scene / "images" / f"view_{i:03d}.jpg", root / "photos" / "a")
    shutil.copytree(root / "b_scene" / "images", root / "photos" / "b")
    return root / "photos"


def test_two_disjoint_scenes_give_two_models_and_the_largest_is_exported(two_scenes, tmp_path):
    ws = tmp_path / "ws"
    proc = cli("run", SPARSE, "--images", two_scenes, "--workspace", ws)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = "sfm: 2 separate models (sizes 12, 8); the largest is sparse/0"
    assert line in proc.stderr and line in (ws / ".recon" / "recon.log").read_text()
    report = read_json(complete_outputs(ws, "sfm")[0] / "models.json")
    assert [m["registered"] for m in report["models"]] == [12, 8]
    assert set(report["unregistered"]) == {f"a/view_{i:03d}.jpg" for i in range(8)}
    assert all(why.startswith("registered in separate model 1") for why in report["unregistered"].values())
    assert {Path(n).parent.name for n in centres(ws)} == {"b"}
    second = pycolmap.Reconstruction(str(ws / "sparse" / "1"))
    assert {Path(img.name).parent.name for img in second.images.values() if img.has_pose} == {"a"}
    frames = json.loads((ws / "transforms.json").read_text())["frames"]
    assert len(frames) == 12 and all(f["file_path"].startswith("images/b/") for f in frames)


# ---------------------------------------------------------------------------------------------
# Sets that cannot be reconstructed


@pytest.mark.parametrize("kind", ["noise", "far_apart"])
def test_a_set_sfm_cannot_reconstruct_says_why_and_keeps_the_matches(kind, tmp_path, small_scene):
    """Noise photos share no verified match: "too few matches". Three views 45 degrees apart match
    (under 100 inliers a pair) but no pair can start a model: "no initial pair". The matches are kept:
    a run with another sfm option runs sfm only."""
    photos = tmp_path / "photos"
    photos.mkdir()
    if kind == "noise":
        rng = np.random.default_rng(0)
        for i in range(3):
            Image.fromarray(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)).save(photos / f"noise_{i}.png")
        why = "Too few matches: no pair of the 3 photos shares 15+ verified matches"
    else:
        for name in ("view_000.jpg", "view_002.jpg", "view_004.jpg"):
            shutil.copy(small_scene / "images" / name, photos / name)
        why = "No initial pair: 3 photos have matches, but no pair has the 100+ verified inliers"
    ws = tmp_path / "ws"
    args = ("run", SPARSE, "--images", photos, "--workspace", ws)
    first = cli(*args)
    message = assert_one_line_error(first, "sfm: no model could be built: the incremental mapper built no model; ")
    assert why in message and ("the global mapper built no model" in message if kind == "noise" else
                               "the global mapper's model has 0 points (under 100: unsound)" in message)
    assert len(complete_outputs(ws, "matching")) == 1 and complete_outputs(ws, "sfm") == []
    again = cli(*args, "-o", "sfm.min_num_matches=8")
    assert "features: running" not in again.stderr and "matching: running" not in again.stderr
    assert "sfm: running" in again.stderr


# ---------------------------------------------------------------------------------------------
# Spaces and non-ASCII characters in paths


def test_paths_with_spaces_and_non_ascii_names(tmp_path, small_scene):
    """Folder and file names with spaces and accents, a workspace and a config file in such folders
    (relative paths): the whole sparse pipeline runs on 6 neighbouring views and finds their poses."""
    root = tmp_path / "mes données ✓"
    photos = root / "photos du jardin" / "été 2024"
    photos.mkdir(parents=True)
    names = {}
    for i in range(6):
        name = f"vue {i:03d} – façade ü.jpg"
        shutil.copy(small_scene / "images" / f"view_{i:03d}.jpg", photos / name)
        names[f"été 2024/{name}"] = f"view_{i:03d}.jpg"
    config = root / "réglages.yaml"
    config.write_text(SPARSE.read_text() + 'images: "photos du jardin"\nworkspace: "résultat final"\n')
    proc = cli("run", config)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ws = root / "résultat final"
    assert "matching: exhaustive, 15 pairs matched" in proc.stderr
    rec = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    est = {names[img.name]: (img.cam_from_world().rotation.matrix(), img.cam_from_world().translation)
           for img in rec.images.values() if img.has_pose}
    assert sorted(est) == sorted(names.values())
    gt = {k: v for k, v in load_cameras(small_scene).items() if k in est}
    figures = pose_metrics(est, gt)
    assert figures["registered"] == 6 and figures["auc@5"] > 80, figures
    frames = json.loads((ws / "transforms.json").read_text())["frames"]
    assert all((ws / f["file_path"]).is_file() for f in frames) and len(frames) == 6
    assert "photo names hold spaces" in proc.stderr  # COLMAP's text format cannot hold them: said once
    status = cli("status", ws)
    assert status.returncode == 0 and all(line.split()[1] == "done" for line in status.stdout.splitlines())
