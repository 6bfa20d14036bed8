"""SIFT features of one photo through pycolmap, at a bounded image size.

COLMAP's default maximum image size (3200 px) with its default first octave (-1, i.e. every image
upsampled 2x inside SIFT) spends most of its time on the finest scales. recon downsizes large photos
with area interpolation (anti-aliased) to ``max_image_size``, upsizes small ones to ``min_image_size``
(a gentler version of the 2x upsampling, which small photos need for enough precise features), runs
SIFT from octave 0, and scales keypoints back to the photo's pixel frame. On temple_ring (640x480),
upsizing to 800 px at octave 0 gave pose AUC@5 80.5 (960 px: 82.0; COLMAP's octave -1: 81.9) for 0.4x
the CPU time of octave -1, and 800 px was the default until the rest of the sparse pipeline had caught up.
With today's pipeline 1024 px pays (docs/DECISIONS.md, session 59): temple_ring AUC@1/3/5 52.9 / 84.0 /
90.4 -> 73.9 / 91.2 / 94.7 in less time (its sparse run 26 -> 20 s: the mapper converges sooner), and
the zoo's cameras come out closer to the truth on 15 of its 17 scenes (median relative rotation error
over all pairs: glossy .137 -> .056 degrees, clutter .041 -> .016). Not 1280: the zoo's walkaround then
broke (AUC@5 25), its photos matching the same window pictures on other facades.

A photo that yields fewer than ``min_num_features`` is extracted again, more sensitively: from
octave -1 (COLMAP's default), then with the peak threshold lowered by a third, twice (as OpenSfM's
``feature_min_frames`` lowers its threshold). Low-contrast texture (marble, plaster, matte paint)
gives few features at octave 0, and a model built on a few hundred points places its cameras
poorly. Measured at 800 px (pose AUC@5 against the truth): the zoo's turntable_black (a marble pedestal
in black, 126-232 features per photo) 77.1 -> 94.2; dino_sparse_ring (136-244) registered 6 of 16
photos (AUC@5 10.6), now 16 of 16 (37.1). Photos with enough features are extracted once, as before.
The threshold grows with the area SIFT sees: 500 at 800 px, 800 at 1024 px. At 1024 px with 500,
turntable_black's photos (503-600 features) were extracted once and its cameras came out worse
(relative rotation error .127 -> .246 degrees; with 800, .143). Why not more: at 1000 (800 px),
temple_ring rose but took 1.6x as long, and walkaround broke (94.8 -> 24.9): its photos with the most
sky (578-967) then matched the same window pictures on other facades; at 1024 px its fewest give 853.
A third step lower (threshold 0.002) cost dino_sparse_ring 13 of its 16 photos: noise, not texture, is
what such a threshold finds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from recon.config import ConfigError
from recon.files import atomic
from recon.imaging.masks import inside_mask, load_mask
from recon.logs import quiet_colmap
from recon.options import opt
from recon.sparse.photos import stored_size

#: extractor types that need pycolmap's ONNX build: on the CPU wheel they abort the whole process
ONNX_ONLY = {"aliked", "aliked_n16", "aliked_n16rot", "aliked_n32", "aliked_t16", "loma", "superpoint",
             "disk", "lightglue"}


@dataclass(frozen=True)
class SiftSettings:
    max_image_size: int
    min_image_size: int
    max_num_features: int
    first_octave: int
    peak_threshold: float
    edge_threshold: float
    estimate_affine_shape: bool
    domain_size_pooling: bool
    upright: bool
    darkness_adaptivity: bool
    min_num_features: int


@dataclass(frozen=True)
class FeaturesConfig:
    type: str = opt("sift", "feature type; only 'sift' runs on the CPU pycolmap wheel")
    max_image_size: int = opt(1600, "longest image side for extraction (photos are downsized, anti-aliased)", gt=0)
    max_num_features: int = opt(8192, "keep at most this many features per photo", gt=0)
    min_image_size: int = opt(1024, "smaller photos are upsized (bicubic) to this longest side for extraction: "
                                    "a 640x480 photo's keypoints then sit finer and its cameras come out more "
                                    "accurate (docs/DECISIONS.md, session 59)", ge=0)
    first_octave: int = opt(0, "SIFT first octave: -1 upsamples 2x inside SIFT (COLMAP's default; slow)",
                            ge=-1, le=3)
    peak_threshold: float = opt(0.0066667, "SIFT peak (contrast) threshold; lower = more features in "
                                           "low-contrast photos", gt=0)
    edge_threshold: float = opt(10.0, "SIFT edge threshold", gt=0)
    estimate_affine_shape: bool = opt(False, "estimate affine keypoint shape (slower, helps wide baselines)")
    domain_size_pooling: bool = opt(False, "DSP-SIFT descriptors (slower, more robust)")
    upright: bool = opt(False, "skip orientation estimation (photos all upright)")
    darkness_adaptivity: bool = opt(False, "adapt the threshold in dark images")
    min_num_features: int = opt(800, "a photo with fewer features is extracted again, more sensitively: from "
                                     "SIFT's octave -1, then with the peak threshold lowered by a third, twice; "
                                     "for low-contrast surfaces. 0 = never", ge=0)
    masks: bool = opt(False, "drop keypoints on masked pixels (preprocess.mask_dir), as COLMAP does: for turntable "
                             "captures, whose background does not move with the object. Off: the background "
                             "helps register the photos, and masks still keep it out of depth, mesh and texture")

    def __post_init__(self):
        if self.type.lower() in ONNX_ONLY:
            raise ConfigError(
                f"features.type: '{self.type}' needs pycolmap built with ONNX support; on the CPU wheel "
                "it aborts the whole process (uncatchable), so recon refuses it. Use 'sift'.")
        if self.type.lower() != "sift":
            raise ConfigError(f"features.type: unknown feature type '{self.type}'; use 'sift'")

    def settings(self) -> SiftSettings:
        return SiftSettings(self.max_image_size, self.min_image_size, self.max_num_features, self.first_octave,
                            self.peak_threshold,
                            self.edge_threshold, self.estimate_affine_shape, self.domain_size_pooling,
                            self.upright, self.darkness_adaptivity, self.min_num_features)


def sensitivity_ladder(settings: SiftSettings) -> list[SiftSettings]:
    """The settings a photo is extracted with, in turn, until it gives ``min_num_features``: its
    own, then from octave -1, then twice with the peak threshold lowered by a third."""
    ladder = [settings, replace(settings, first_octave=min(settings.first_octave, -1))]
    for _ in range(2):
        ladder.append(replace(ladder[-1], peak_threshold=ladder[-1].peak_threshold * 2 / 3))
    return ladder


def extract_photo(task: tuple[Path, Path, SiftSettings, Path | None]) -> int:
    """One photo's SIFT (source, destination .npz, settings, mask folder or None), in a worker; its count."""
    source, dest, settings, mask_dir = task
    quiet_colmap()  # a worker process: COLMAP's info lines would flood the terminal
    mask = load_mask(mask_dir, dest.name.removesuffix(".npz")) if mask_dir is not None else None
    for tried in sensitivity_ladder(settings):
        keypoints, descriptors = extract_sift(source, tried)
        if mask is not None:
            keep = inside_mask(mask, keypoints[:, :2])
            keypoints, descriptors = keypoints[keep], descriptors[keep]
        if len(keypoints) >= settings.min_num_features:
            break
    save_features(dest, keypoints, descriptors)
    return len(keypoints)


#: JPEG decoding at 1/8, 1/4, 1/2 scale (libjpeg's DCT scaling: cheap, and it averages like an area filter)
_REDUCED = ((8, cv2.IMREAD_REDUCED_GRAYSCALE_8), (4, cv2.IMREAD_REDUCED_GRAYSCALE_4),
            (2, cv2.IMREAD_REDUCED_GRAYSCALE_2))


def load_gray(path: Path, max_size: int, min_size: int = 0) -> tuple[np.ndarray, float, float]:
    """The photo in 8-bit grey, downsized to ``max_size`` with area interpolation (or upsized to
    ``min_size``, bicubic, when smaller); and the scales from these pixels to the photo's.

    A JPEG much larger than ``max_size`` is decoded at the largest 1/2, 1/4 or 1/8 reduction that
    still exceeds ``max_size``, so a 12000 px photo never occupies memory at full size.
    """
    flag, (w, h) = cv2.IMREAD_GRAYSCALE, stored_size(path)
    if max_size > 0 and path.suffix.lower() in (".jpg", ".jpeg"):
        flag = next((f for k, f in _REDUCED if max(w, h) / k >= max_size), flag)
    img = cv2.imread(str(path), flag)
    if img is None:
        raise OSError(f"{path}: cannot read image")
    if (img.shape[0] > img.shape[1]) != (h > w):  # OpenCV applied an EXIF rotation
        w, h = h, w
    scale = min(1.0, max_size / max(img.shape)) if max_size > 0 else 1.0
    if min_size > max(img.shape):
        scale = min_size / max(img.shape)
    if scale != 1.0:
        size = (max(1, round(img.shape[1] * scale)), max(1, round(img.shape[0] * scale)))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA if scale < 1.0 else cv2.INTER_CUBIC)
    return np.ascontiguousarray(img), w / img.shape[1], h / img.shape[0]


def extract_sift(path: Path, s: SiftSettings) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints (N x 4: x, y, scale, orientation; photo pixel frame) and uint8 descriptors (N x 128)."""
    import pycolmap

    img, sx, sy = load_gray(path, s.max_image_size, s.min_image_size)
    opts = pycolmap.FeatureExtractionOptions()
    opts.num_threads = 1
    opts.max_image_size = -1
    sift = opts.sift
    sift.max_num_features = s.max_num_features
    sift.first_octave = s.first_octave
    sift.peak_threshold = s.peak_threshold
    sift.edge_threshold = s.edge_threshold
    sift.estimate_affine_shape = s.estimate_affine_shape
    sift.domain_size_pooling = s.domain_size_pooling
    sift.upright = s.upright
    sift.darkness_adaptivity = s.darkness_adaptivity
    extractor = pycolmap.FeatureExtractor.create(opts, pycolmap.Device.cpu)
    kp, desc = extractor.extract(pycolmap.Bitmap.from_array(img))
    keypoints = pycolmap.keypoints_to_matrix(kp).astype(np.float32)
    if keypoints.shape[1] == 6:  # affine shape: (x, y, a11, a12, a21, a22)
        keypoints[:, 2:] *= np.float32((sx + sy) / 2)
    else:
        keypoints[:, 2] *= np.float32((sx + sy) / 2)
    keypoints[:, 0] *= np.float32(sx)
    keypoints[:, 1] *= np.float32(sy)
    return keypoints, np.ascontiguousarray(desc.data, dtype=np.uint8)


def save_features(path: Path, keypoints: np.ndarray, descriptors: np.ndarray) -> None:
    """Write one photo's features atomically (a kill never leaves a half-written file)."""
    with atomic(path) as tmp:
        np.savez(tmp, keypoints=keypoints, descriptors=descriptors)


def load_features(path: Path) -> tuple[np.ndarray, np.ndarray]:
    with np.load(path) as data:
        return data["keypoints"], data["descriptors"]
