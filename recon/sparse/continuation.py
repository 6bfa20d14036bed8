"""Continuing a finished model with new photos instead of mapping them all again.

COLMAP's incremental mapper starts from an existing reconstruction when given one
(``incremental_mapping(..., input_path=...)``): it registers the database's other images into it,
triangulates and bundle-adjusts. The reconstruction must speak the database's ids, and a photo
added to the folder shifts them (ids follow the names' order), so :func:`start_model` rewrites the
previous model with the current ids: same cameras, poses, keypoints and tracks.

:func:`continue_model` keeps the previous photos' poses fixed (``fix_existing_frames``): the
previous model had its final robust bundle adjustment already, and the new photos are adjusted
against it (the mapper's local and global BA; cameras' intrinsics still refined), with no final BA
over the whole model. Measured on temple_ring, 40 photos then 7 added (loaded machine): the
continuation took 12.5 s against 32.5 s with the previous poses free and the final BA, AUC@5 91.7
against 90.7 (90.3 from scratch); the previous photos stay exactly where they were, so their depth
maps stay valid (:mod:`recon.mvs.reuse`). A model the mapper builds apart
from the previous one (new photos that join none) gets the final BA as from scratch.
:func:`align_to_previous` still fits the result onto the previous model's frame on the photos
both registered (the identity, when the mapper kept them fixed), so every output made in that frame
(levelled, or georeferenced) stays in it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.geometry.transforms import align_similarity
from recon.sparse import mapping
from recon.sparse.database import read_only


def continue_model(database: Path, images: Path, cfg, seed: int, start) -> mapping.Mapping:
    """The models of the incremental mapper continuing ``start`` (:func:`start_model`) with the
    database's other photos, the previous photos' poses fixed (module doc); largest first."""
    models = mapping.continued(start, database, images, cfg, seed, cfg.multiple_models)
    previous = {image.name for image in start.images.values()}
    ordered = sorted(models.values(), key=lambda r: (-r.num_reg_images(), -r.num_points3D()))
    if cfg.final_ba_iterations:
        initial, exif = mapping.camera_start(database)
        ordered = [rec if previous & {i.name for i in rec.images.values()} else
                   mapping.final_bundle_adjustment(rec, cfg, initial, exif) for rec in ordered]
    attempt = mapping.Attempt.of("incremental", ordered)
    return mapping.Mapping(ordered, "incremental", "continued the previous model (its photos' poses fixed)",
                           [attempt])


def start_model(previous, image_ids: dict[str, int], camera_ids: dict[str, int],
                camera_shapes: dict[int, tuple[int, int, int]]):
    """``previous`` (a pycolmap Reconstruction) with the current database's ids: ``image_ids`` and
    ``camera_ids`` give each image name its image id and camera id, ``camera_shapes`` each camera id
    its (COLMAP model id, width, height). None when the previous model holds an image the database
    lacks, one camera that the database splits in two, or a camera of another model or size (the
    photos' lens settings changed: the model is mapped again, not continued)."""
    import pycolmap

    names = {image.name for image in previous.images.values()}
    if not names <= image_ids.keys():
        return None
    cameras: dict[int, int] = {}
    for image in previous.images.values():
        if cameras.setdefault(image.camera_id, camera_ids[image.name]) != camera_ids[image.name]:
            return None
    rec = pycolmap.Reconstruction()
    for old_id, new_id in cameras.items():
        old = previous.cameras[old_id]
        if (int(old.model.value), old.width, old.height) != camera_shapes[new_id]:
            return None
        camera = pycolmap.Camera(model=old.model, width=old.width, height=old.height, params=old.params,
                                 camera_id=new_id)
        camera.has_prior_focal_length = old.has_prior_focal_length
        rec.add_camera_with_trivial_rig(camera)
    new_ids = {}
    for image in previous.images.values():
        new_ids[image.image_id] = image_ids[image.name]
        keypoints = np.array([p.xy for p in image.points2D], dtype=np.float64).reshape(-1, 2)
        copy = pycolmap.Image(name=image.name, keypoints=keypoints, camera_id=cameras[image.camera_id],
                              image_id=image_ids[image.name])
        rec.add_image_with_trivial_frame(copy, image.cam_from_world())
    for point in previous.points3D.values():
        track = pycolmap.Track()
        for element in point.track.elements:
            track.add_element(new_ids[element.image_id], element.point2D_idx)
        rec.add_point3D(point.xyz, track, point.color)
    return rec


def align_to_previous(rec, previous, seed: int = 0) -> dict | None:
    """Move ``rec`` (in place) into the frame of ``previous`` by the similarity that best maps its
    photos' centres onto theirs in ``previous`` (robust: a photo the new photos moved is left out).
    Returns the photos used, the scale applied and the centres' RMS residual in the previous
    frame's units; None when the two share fewer than 3 registered photos."""
    import pycolmap

    before = {image.name: image.projection_center() for image in previous.images.values() if image.has_pose}
    now = {image.name: image.projection_center() for image in rec.images.values() if image.has_pose}
    shared = sorted(before.keys() & now.keys())
    if len(shared) < 3:
        return None
    src = np.array([now[n] for n in shared])
    dst = np.array([before[n] for n in shared])
    sim, used = align_similarity(src, dst, robust=True, seed=seed)
    rec.transform(pycolmap.Sim3d(sim.s, pycolmap.Rotation3d(sim.R), sim.t))
    residual = np.linalg.norm(sim.apply(src[used]) - dst[used], axis=1)
    return {"photos": int(used.sum()), "shared": len(shared), "scale": float(sim.s),
            "rms": float(np.sqrt(np.mean(residual ** 2)))}


def database_ids(database: Path) -> tuple[dict[str, int], dict[str, int], dict[int, tuple[int, int, int]]]:
    """Image name -> image id, image name -> camera id, and camera id -> (COLMAP model id, width,
    height), in a COLMAP database."""
    with read_only(database) as db:
        rows = db.execute("SELECT name, image_id, camera_id FROM images").fetchall()
        cameras = db.execute("SELECT camera_id, model, width, height FROM cameras").fetchall()
    return ({name: image for name, image, _ in rows}, {name: camera for name, _, camera in rows},
            {camera: (model, width, height) for camera, model, width, height in cameras})
