"""GPS positions as priors in one last bundle adjustment, for photos whose GPS is accurate (RTK/PPK).

Why only accurate GPS: a block of nadir photos over gently rolling ground lets bundle adjustment bend
the whole block into a bowl while the radial distortion term makes up for it (the "bowl" or "doming"
effect of aerial surveys); the photos hardly see it. Measured on the 300-view synthetic survey of
``make bench-scale`` (pinhole camera, SIMPLE_RADIAL estimated; model from spatial matching): the
camera centres' vertical error was 96 % a quadratic bowl, per-photo tilt error correlated 0.96 with
the squared distance from the block's centre; fixing k1 at 0 and adjusting again raised pairwise pose
AUC@1 from 68.0 to 89.6, and freeing k1 from there dropped it to 5.5 while the reprojection error
moved by 0.03 %. Position priors flatten the bowl only when they are more accurate than the bend:
priors of 0.05 m took AUC@1 from 68.0 to 93.1, 0.3 m to 86.0, but 1 m to 53.9 and 3 m (phone or plain
drone GPS) to 9.6: weak priors leave the adjustment free to slide further along the bowl. So ``auto``
uses them when the photos' stated accuracy is at most :data:`AUTO_MAX_SIGMA`.

Coarse GPS does pay where the photos fall into groups tied to each other by few 3D points
(:mod:`recon.sparse.weak_joins`): there the photos leave the groups' relative placement loose (a walk
round a building meets each corner with one pair of photos; the loop of facades does not fix their
lengths' ratio), and the GPS positions hold information the photos lack. On the zoo's walk at
512x384 (GPS 3 m off; four verified-pair sets, ``seed`` 0-3, the global mapper's model), pose AUC@5
92.8 / 28.6 / 27.3 / 28.6 without priors, 92.8 / 49.7 / 46.0 / 30.1 with them; at 640x480, where the
model is right, 95.2 / 95.1 / 95.3 against 95.2 / 95.0 / 95.3. So ``auto`` uses them there too.

pycolmap's pose-prior bundle adjuster does the work (positions with covariances, Cartesian ENU); only
the photos the robust GPS alignment kept as inliers get a prior.
"""

from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)

#: ``auto`` adds GPS priors when the median stated accuracy of the photos is at most this (metres)
AUTO_MAX_SIGMA = 0.5
#: iterations of the prior bundle adjustment
ITERATIONS = 100


def decide(mode: str, sigmas: np.ndarray, groups: int = 1) -> tuple[bool, str]:
    """Whether to adjust with GPS priors (``mode``: auto / on / off; ``sigmas``: the inlier photos'
    GPS accuracies, metres; ``groups``: how many groups of photos tied to each other by few points the
    model has, :mod:`recon.sparse.weak_joins`) and why, in words for georeference.json."""
    median = float(np.median(sigmas))
    if mode == "off":
        return False, "sfm.gps_prior is off"
    if mode == "on":
        return True, "sfm.gps_prior is on"
    if median <= AUTO_MAX_SIGMA:
        return True, f"the photos' GPS is accurate (median {median:.3g} m <= {AUTO_MAX_SIGMA} m)"
    if groups > 1:
        return True, (f"the model's photos fall into {groups} groups tied to each other by few 3D points: GPS "
                      f"(median accuracy {median:.3g} m) places them against each other")
    return False, (f"the photos' GPS accuracy (median {median:.3g} m) is above {AUTO_MAX_SIGMA} m: as a prior it "
                   "would bend a nadir block more than it straightens it (set sfm.gps_prior: on to use it anyway)")


def adjust(model, names: list[str], positions: np.ndarray, sigmas: np.ndarray, options) -> dict:
    """Bundle-adjust ``model`` (a pycolmap Reconstruction already in the GPS frame, metres) in place with
    each named photo's camera centre pulled toward its GPS position ``positions`` (N, 3) with standard
    deviation ``sigmas`` (N,); ``options``: pycolmap BundleAdjustmentOptions (what to refine). Returns
    the mean reprojection error before and after, and the photos used."""
    import pycolmap

    ids = {model.image(i).name: model.image(i) for i in model.reg_image_ids()}
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in model.reg_image_ids():
        config.add_image(image_id)
    priors = []
    for name, position, sigma in zip(names, positions, sigmas, strict=True):
        prior = pycolmap.PosePrior()
        prior.corr_data_id = ids[name].data_id
        prior.position = np.asarray(position, float)
        prior.position_covariance = np.eye(3) * float(sigma) ** 2
        prior.coordinate_system = pycolmap.PosePriorCoordinateSystem.CARTESIAN
        priors.append(prior)
    options.ceres.solver_options.max_num_iterations = ITERATIONS
    before = model.compute_mean_reprojection_error()
    adjuster = pycolmap.create_pose_prior_bundle_adjuster(options, pycolmap.PosePriorBundleAdjustmentOptions(),
                                                          config, priors, model)
    adjuster.solve()
    model.update_point_3d_errors()  # the adjuster leaves the points' stored errors as they were
    after = model.compute_mean_reprojection_error()
    log.info("GPS prior bundle adjustment: %d photos, mean reprojection error %.3f -> %.3f px",
             len(priors), before, after)
    return {"photos": len(priors), "reprojection_error_px": {"before": before, "after": after}}
