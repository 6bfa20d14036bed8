"""Camera pose accuracy against ground truth: pairwise relative-pose AUC and camera-centre error.

Relative-pose AUC (as in glue-factory / LightGlue's ``cal_error_auc``): over ALL unordered pairs of
ground-truth images, the error of a pair is max(angle of the relative-rotation error, angle between
the relative translation directions) in degrees; a pair with an unregistered image counts 180.
Relative poses are gauge-free, so no alignment is needed. The translation direction is compared
with its sign (SfM fixes it, unlike an essential matrix), and an error is 0 when either translation
is zero. AUC@T is the area under the recall-vs-error curve from 0 to T divided by T, in percent.

Camera-centre error: estimated centres are aligned to ground-truth centres with a robust similarity
(least-median-of-squares over 3-point samples, then Umeyama on the inliers); the median distance
over registered images is ``median_center_error`` (ground-truth units). ``median_center_error_rel``
divides it by the ground-truth camera spread: the median distance of all ground-truth centres to
their centroid (the ring radius for an orbit). Both are NaN with fewer than 3 registered images.
"""

from __future__ import annotations

import numpy as np

from recon.eval.groundtruth import Camera
from recon.geometry.transforms import align_similarity, camera_center, rotation_angles_deg

AUC_THRESHOLDS = (1.0, 3.0, 5.0)


def pose_metrics(est: dict[str, tuple[np.ndarray, np.ndarray]], gt: dict[str, Camera]) -> dict:
    """Pose metrics of estimated world-to-camera poses ``est`` (name -> (R, t)) against ``gt``.

    Returns ``registered`` (ground-truth images with an estimate), ``total`` (= len(gt)),
    ``auc@1``, ``auc@3``, ``auc@5`` (percent), ``median_center_error``, ``median_center_error_rel``.
    Estimates for images not in ``gt`` are ignored.
    """
    names = sorted(gt)
    reg = np.array([n in est for n in names])
    n = len(names)
    R_gt = np.stack([gt[k].R for k in names]) if n else np.zeros((0, 3, 3))
    t_gt = np.stack([gt[k].t for k in names]) if n else np.zeros((0, 3))
    R_est = np.stack([np.asarray(est[k][0], float) if r else np.eye(3) for k, r in zip(names, reg, strict=True)]) \
        if n else np.zeros((0, 3, 3))
    t_est = np.stack([np.asarray(est[k][1], float).reshape(3) if r else np.zeros(3)
                      for k, r in zip(names, reg, strict=True)]) if n else np.zeros((0, 3))

    i, j = np.triu_indices(n, k=1)
    errors = np.maximum(_rotation_errors(R_est, R_gt, i, j), _translation_errors(R_est, t_est, R_gt, t_gt, i, j))
    errors[~(reg[i] & reg[j])] = 180.0
    out = {"registered": int(reg.sum()), "total": n, "pairs": len(errors)}
    for thr, auc in zip(AUC_THRESHOLDS, pose_auc(errors, AUC_THRESHOLDS), strict=True):
        out[f"auc@{thr:g}"] = auc
    out.update(_center_errors(R_est[reg], t_est[reg], R_gt, t_gt, reg))
    return out


def pose_auc(errors: np.ndarray, thresholds=AUC_THRESHOLDS) -> list[float]:
    """Area under the recall-vs-error curve up to each threshold, divided by it, in percent."""
    errors = np.sort(np.asarray(errors, dtype=float))
    if len(errors) == 0:
        return [float("nan")] * len(thresholds)
    recall = np.arange(1, len(errors) + 1) / len(errors)
    errors = np.r_[0.0, errors]
    recall = np.r_[0.0, recall]
    aucs = []
    for thr in thresholds:
        last = np.searchsorted(errors, thr)
        r = np.r_[recall[:last], recall[last - 1]]
        e = np.r_[errors[:last], thr]
        aucs.append(float(np.trapezoid(r, x=e) / thr * 100.0))
    return aucs


def _rotation_errors(R_est, R_gt, i, j) -> np.ndarray:
    rel_est = np.einsum("pab,pcb->pac", R_est[j], R_est[i])  # R_j R_i^T
    rel_gt = np.einsum("pab,pcb->pac", R_gt[j], R_gt[i])
    return rotation_angles_deg(np.einsum("pba,pbc->pac", rel_est, rel_gt))  # rel_est^T rel_gt


def _translation_errors(R_est, t_est, R_gt, t_gt, i, j) -> np.ndarray:
    def rel_t(R, t):
        rel = np.einsum("pab,pcb->pac", R[j], R[i])
        return t[j] - np.einsum("pab,pb->pa", rel, t[i])

    a, b = rel_t(R_est, t_est), rel_t(R_gt, t_gt)
    cross = np.linalg.norm(np.cross(a, b), axis=1)
    return np.degrees(np.arctan2(cross, np.einsum("pa,pa->p", a, b)))


def _center_errors(R_est, t_est, R_gt, t_gt, reg) -> dict:
    c_gt_all = np.stack([camera_center(R, t) for R, t in zip(R_gt, t_gt, strict=True)]) if len(R_gt) else np.zeros((0, 3))
    spread = float(np.median(np.linalg.norm(c_gt_all - c_gt_all.mean(0), axis=1))) if len(c_gt_all) else 0.0
    if reg.sum() < 3:
        return {"median_center_error": float("nan"), "median_center_error_rel": float("nan")}
    c_est = np.stack([camera_center(R, t) for R, t in zip(R_est, t_est, strict=True)])
    c_gt = c_gt_all[reg]
    sim, _ = align_similarity(c_est, c_gt, robust=True)
    err = float(np.median(np.linalg.norm(sim.apply(c_est) - c_gt, axis=1)))
    return {"median_center_error": err, "median_center_error_rel": err / spread if spread > 0 else float("nan")}
