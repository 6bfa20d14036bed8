"""2D-3D correspondences of a new photo: its SIFT matches with retrieved reference images, kept
where the reference keypoint belongs to a 3D point of the model.

Matching is COLMAP's SIFT matching (:func:`recon.sparse.sift_match.sift_matches`). A photo is matched against ALL keypoints of a reference image, not only the
triangulated ones, so the ratio test is as discriminative as in the reference's own matching. A
photo keypoint matching keypoints of several images of one 3D point gives that pair once; one
matched to different 3D points keeps each candidate (RANSAC decides), as COLMAP's registrator does.
"""

from __future__ import annotations

import numpy as np

from recon.localize.options import LocalizeOptions
from recon.localize.reference import Reference
from recon.sparse.sift_match import sift_matches


def correspondences(reference: Reference, image_ids: list[int], descriptors: np.ndarray,
                    options: LocalizeOptions) -> tuple[np.ndarray, np.ndarray]:
    """Unique (photo keypoint index, 3D point id) pairs from matching ``descriptors`` with each image
    of ``image_ids``; two int64 arrays of equal length."""
    pairs = [np.zeros((0, 2), np.int64)]
    for image_id in image_ids:
        m = sift_matches(descriptors, reference.descriptors[image_id], options.max_ratio, options.max_distance,
                         options.cross_check)
        point_ids = reference.point3D_ids[image_id][m[:, 1]]
        keep = point_ids >= 0
        pairs.append(np.column_stack([m[keep, 0], point_ids[keep]]))
    unique = np.unique(np.concatenate(pairs), axis=0)
    return unique[:, 0], unique[:, 1]
