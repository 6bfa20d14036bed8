"""Running COLMAP's mappers and explaining which photos did not register, and why."""

from __future__ import annotations

import logging
import sqlite3
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from recon.sparse.database import (
    cameras_with_exif_focal,
    image_ids,
    opened,
    private_copy,
    read_only,
    stored_camera_params,
)
from recon.sparse.pose_check import (
    MIN_AGREEING,
    contradicted,
    pair_agreement,
    pair_pixels,
    take_out_contradicted,
)
from recon.sparse.residuals import observation_errors

log = logging.getLogger(__name__)


#: the incremental mapper falls short when its largest model holds fewer than this share of the photos
#: (or the photos split into several models); the global mapper is then run too
FALLBACK_MIN_SHARE = 0.95
#: a model is sound when its mean reprojection error (after the final BA; :func:`capped_mean_error`, so
#: that one observation thousands of pixels off does not decide) is at most this, pixels: SIFT models are
#: at 0.2-1 px (temple_ring 0.6, the walk-around zoo scene 0.2-0.3)
MAX_SOUND_REPROJ_ERROR = 2.0
#: ... and it holds at least this many points: COLMAP's global mapper, given three photos with 16-30
#: inliers a pair (no pair can start the incremental mapper), returned a "model" of 4 points at 0.0 px.
#: The incremental mapper needs 100 verified inliers to start a model; a kept model needs as many points
MIN_SOUND_POINTS = 100
#: fewer photos than this share in the largest model ends sfm with a warning (:func:`left_out_warning`)
WARN_REGISTERED_SHARE = 0.75


@dataclass(frozen=True)
class Attempt:
    """What one mapper made: photos in its largest model, how many models, that model's mean
    reprojection error (pixels, each observation's capped: :func:`capped_mean_error`; None without a
    model) and its 3D points."""

    mapper: str
    registered: int
    models: int
    mean_reproj_error: float | None
    points: int = 0

    @staticmethod
    def of(mapper: str, models: list) -> Attempt:
        if not models:
            return Attempt(mapper, 0, 0, None)
        best = models[0]
        return Attempt(mapper, best.num_reg_images(), len(models), capped_mean_error(best), best.num_points3D())

    def describe(self, photos: int) -> str:
        if not self.models:
            return f"the {self.mapper} mapper built no model"
        split = f", the rest split into {self.models - 1} more" if self.models > 1 else ""
        return f"the {self.mapper} mapper's largest model holds {self.registered} of {photos} photos{split}"


@dataclass
class Mapping:
    """The models kept (largest first), the mapper that made them and why that one, and what each
    mapper run made; the photos taken out of the kept models, and why (:mod:`recon.sparse.pose_check`);
    the verified pairs the global mapper left out as false (:func:`_global_mapping`)."""

    models: list
    mapper: str
    why: str
    attempts: list[Attempt]
    taken_out: dict[str, str] = field(default_factory=dict)
    false_pairs: list[str] = field(default_factory=list)


def reconstruct(database: Path, images: Path, cfg, seed: int, start=None) -> Mapping:
    """All models the mapper ``cfg.mapper`` builds, largest first (``cfg`` is the sfm stage's config),
    each refined by :func:`final_bundle_adjustment`. ``start``: a model in the database's ids
    (:func:`recon.sparse.continuation.start_model`) that the incremental mapper continues.

    With ``cfg.mapper_fallback``, where the incremental mapper falls short (:func:`shortfall`), the
    global mapper runs too and the result that registers more photos at a sound reprojection error
    is kept (:func:`choose`): on a walk round a building, photos past a corner share too few matches
    with the model for the incremental mapper to register them (a model per facade), while the
    global mapper, which needs only each pair's geometry, joins them."""
    with read_only(database) as db:
        photos = len(image_ids(db))
    taken_out: dict[str, dict[str, str]] = {cfg.mapper: {}, "global": {}}
    false_pairs: list[str] = []  # the global mapper's, whichever run made them
    models = _map(cfg.mapper, database, images, cfg, seed, start, taken_out[cfg.mapper], false_pairs)
    first = Attempt.of(cfg.mapper, models)
    short = shortfall(first, photos) if cfg.mapper == "incremental" else None
    if short is None or not cfg.mapper_fallback:
        why = f"sfm.mapper is {cfg.mapper}" + (f" ({short}; sfm.mapper_fallback is off)" if short else "")
        return Mapping(models, cfg.mapper, why, [first], taken_out[cfg.mapper], false_pairs)
    log.info("sfm: %s: running the global mapper too", short)
    fallback = _map("global", database, images, cfg, seed, taken_out=taken_out["global"], false_pairs=false_pairs)
    second = Attempt.of("global", fallback)
    mapper, why = choose(first, second, photos)
    log.info("sfm: %s model kept: %s", mapper, why)
    return Mapping(fallback if mapper == "global" else models, mapper, why, [first, second], taken_out[mapper],
                   false_pairs if mapper == "global" else [])


def shortfall(attempt: Attempt, photos: int) -> str | None:
    """Why the incremental mapper's result falls short (its largest model holds under
    :data:`FALLBACK_MIN_SHARE` of the photos, or the photos split into several models), or None."""
    if attempt.models == 1 and attempt.registered >= FALLBACK_MIN_SHARE * photos:
        return None
    return attempt.describe(photos)


def choose(incremental: Attempt, fallback: Attempt, photos: int) -> tuple[str, str]:
    """The mapper whose models are kept after the fallback ran, and why: the global mapper's where its
    largest model registers more photos at a mean reprojection error up to
    :data:`MAX_SOUND_REPROJ_ERROR` with :data:`MIN_SOUND_POINTS` points, else the incremental mapper's."""
    short = incremental.describe(photos)
    if not fallback.models:
        return "incremental", f"{short}; the global mapper built no model"
    if fallback.mean_reproj_error > MAX_SOUND_REPROJ_ERROR:
        return "incremental", (f"{short}; the global mapper's model has a mean reprojection error of "
                               f"{fallback.mean_reproj_error:.2f} px (over {MAX_SOUND_REPROJ_ERROR:g} px: unsound)")
    if fallback.points < MIN_SOUND_POINTS:
        return "incremental", (f"{short}; the global mapper's model has {fallback.points} points "
                               f"(under {MIN_SOUND_POINTS}: unsound)")
    if fallback.registered <= incremental.registered:
        return "incremental", f"{short}; the global mapper's largest model holds no more ({fallback.registered})"
    return "global", f"{short}; {fallback.describe(photos)}"


def _map(mapper: str, database: Path, images: Path, cfg, seed: int, start=None,
         taken_out: dict[str, str] | None = None, false_pairs: list[str] | None = None) -> list:
    """The mapper's models, largest first, without the photos whose pose their strongest verified pairs
    contradict (:mod:`recon.sparse.pose_check`) unless they register again soundly into the model without
    them (:func:`_registered_again`; the names and why of those left out into ``taken_out``), each refined
    by :func:`final_bundle_adjustment`. The global mapper's verified pairs left out as false go into
    ``false_pairs`` (:func:`_global_mapping`)."""
    import pycolmap

    pycolmap.set_random_seed(seed)
    with tempfile.TemporaryDirectory(prefix="recon-sfm-") as scratch, private_copy(database) as copy:
        start_path = ""
        if start is not None:
            start_path = str(Path(scratch) / "start")
            Path(start_path).mkdir()
            start.write(start_path)
            scratch = str(Path(scratch) / "models")
            Path(scratch).mkdir()
        if mapper == "global":
            models = _global_mapping(database, copy, images, scratch, cfg, seed, false_pairs)
        else:
            models = pycolmap.incremental_mapping(str(copy), str(images), scratch,
                                                  incremental_options(cfg, seed), input_path=start_path)
    kept = []
    for rec in models.values():
        dropped = take_out_contradicted(rec, database)
        if dropped:
            rec = _registered_again(rec, database, images, cfg, seed)
            names = {image.name for image in rec.images.values() if image.has_pose}
            dropped = {name: why for name, why in dropped.items() if name not in names}
        if taken_out is not None:
            taken_out |= dropped
        kept.append(rec)
    ordered = sorted(kept, key=lambda r: (-r.num_reg_images(), -r.num_points3D()))
    if cfg.final_ba_iterations:
        initial, exif = camera_start(database)
        ordered = [final_bundle_adjustment(rec, cfg, initial, exif) for rec in ordered]
    return ordered


def continued(start, database: Path, images: Path, cfg, seed: int, multiple_models: bool) -> dict:
    """The incremental mapper's models continuing ``start`` (a model in the database's ids) with the
    database's other photos, ``start``'s photos' poses fixed; with ``multiple_models``, also the models
    it builds apart from ``start`` of photos that join none of it."""
    import pycolmap

    opts = incremental_options(cfg, seed)
    opts.fix_existing_frames = True
    opts.multiple_models = multiple_models
    pycolmap.set_random_seed(seed)
    with tempfile.TemporaryDirectory(prefix="recon-sfm-") as scratch, private_copy(database) as copy:
        given, made = Path(scratch) / "start", Path(scratch) / "models"
        given.mkdir()
        made.mkdir()
        start.write(str(given))
        return pycolmap.incremental_mapping(str(copy), str(images), str(made), opts, input_path=str(given))


def _registered_again(rec, database: Path, images: Path, cfg, seed: int):
    """``rec``, which photos were taken out of (:func:`recon.sparse.pose_check.take_out_contradicted`),
    continued by the incremental mapper with its photos' poses fixed: where that registers more photos
    and the pose check contradicts none, the continued model, else ``rec``.

    A photo taken out was not always registered through false matches: on glossy (24 photos at 640x480,
    ``seed`` 1) view_016 was one of the mapper's initial pair and kept a pose its neighbours' 620 and
    478 verified inliers contradict (0 % and 7 % agree); the rest of the model was right. Taken out, it
    left its pose AUC@5 at 90.6 (98.7 with seeds 0 and 2); registered again into the mended model, through
    those same neighbours, 98.9, for 0.3 s more. A photo whose matches to the model are false can register
    wrongly again: the check then finds it, and ``rec`` is kept."""
    models = continued(rec, database, images, cfg, seed, multiple_models=False)
    again = _largest(models) if models else None
    if again is None or again.num_reg_images() <= rec.num_reg_images() or contradicted(again, database):
        log.info("sfm: the photos taken out do not register again soundly; left out")
        return rec
    log.info("sfm: registered again into the model without them: %d photos (from %d)", again.num_reg_images(),
             rec.num_reg_images())
    return again


#: the most re-runs of the global mapper without contradicted pairs (:func:`_global_mapping`) ...
MAX_REMAPS = 24
#: ... which stop once this many runs in a row, after one that registered every photo the first did,
#: have not lowered the count of inliers in contradicted pairs
PATIENCE = 4


def _global_mapping(database: Path, copy: Path, images: Path, scratch: str, cfg, seed: int,
                    false_pairs: list[str] | None) -> dict:
    """COLMAP's global mapper on ``copy`` (a private copy of ``database``), and again without the
    verified pairs its largest model contradicts (most of a pair's inliers off the epipolar geometry
    of the two poses: :func:`recon.sparse.pose_check.pair_agreement`) where that explains the pairs
    better. The pairs left out are described into ``false_pairs``.

    A contradicted pair is false (matched through look-alike texture, which barely passes verification)
    or true, contradicted because false ones bent the model. So the mapper runs without all of them,
    then with the strongest put back one by one (at most :data:`MAX_REMAPS` runs, until a run agrees
    with every pair it was given, or :data:`PATIENCE` runs after the best); of the runs that register
    as many photos as the first, the one with the fewest of the first model's pairs' inliers in pairs
    it contradicts is kept, where that is fewer than the first model's.

    Why: the global mapper averages every pair's relative rotation, so a few false pairs can turn a
    block of photos tied to the rest by few true ones. On the zoo's walk round a building (29 photos at
    512x384), two pairs matched across opposite facades through look-alike windows (15 and 16 inliers)
    turned one facade about 3 degrees: pose AUC@5 63.1 at a mean reprojection error as low as a right
    model's. The model contradicted those two and the corner pair that ties the facade to its
    neighbour (24 inliers, 4 % agree). Without all three the facade's 6 photos were lost; with the
    corner pair put back, AUC@5 92.8. (The walk's other match sets, ``seed`` 1-3, stay wrong without
    their false pairs, 27-29: there the facades' lengths are loose, :mod:`recon.sparse.gps_prior`.)
    At 640x480, with ``seed`` 1, 4 and 6 (3 of seeds 0-7), the false pairs (14-16, 15-22 inliers each)
    bent the first model so far that it contradicted 11-14 true pairs too (up to 255 inliers); the right
    model came with 5 to 10 of the strongest put back, where a limit of 6 runs had kept bent ones (pose
    AUC@5 47.9, 12.9, 20.7 -> 96.9, 95.9, 95.7; the other five seeds' models unchanged)."""
    import pycolmap

    opts = _common_options(pycolmap.GlobalPipelineOptions(), cfg, seed)
    first = pycolmap.global_mapping(str(copy), str(images), scratch, opts)
    if not first:
        return first
    largest = _largest(first)
    pixels = pair_pixels(largest, database, cfg.min_num_matches)  # read once, judged against each run
    checked = pair_agreement(largest, pixels)
    inliers = {p: len(pixels[p][0]) for p in checked}
    false = sorted((p for p, share in checked.items() if share < MIN_AGREEING), key=lambda p: -inliers[p])  # strongest first
    if not false:
        return first
    names = {i: largest.image(i).name for i in largest.reg_image_ids()}

    def described(pair_ids) -> list[str]:
        return [f"{names[a]} / {names[b]} ({inliers[p]} inliers, {checked[p]:.0%} agree)"
                for p in pair_ids for a, b in [pycolmap.pair_id_to_image_pair(p)]]

    def contradicted_inliers(model) -> int:  # of the first model's checked pairs
        found = pair_agreement(model, {p: pixels[p] for p in checked})
        return sum(inliers[p] for p in checked if found.get(p, 0.0) < MIN_AGREEING)

    log.info("sfm: the global mapper's model contradicts %d verified pairs: %s", len(false), ", ".join(described(false)))
    best, best_count, best_left_out = first, sum(inliers[p] for p in false), []
    since_best = None  # runs since the best, counted from the first run that registered every photo
    for put_back in range(min(len(false), MAX_REMAPS)):
        left_out = false[put_back:]
        with private_copy(copy) as without, tempfile.TemporaryDirectory(prefix="recon-sfm-") as out:
            with sqlite3.connect(without) as db:
                db.executemany("DELETE FROM two_view_geometries WHERE pair_id = ?", [(p,) for p in left_out])
            pycolmap.set_random_seed(seed)  # as for the first run: each run's result depends on its pairs alone
            again = pycolmap.global_mapping(str(without), str(images), out, opts)
        registered = _largest(again).num_reg_images() if again else 0
        count = contradicted_inliers(_largest(again)) if registered >= largest.num_reg_images() else None
        log.info("sfm: mapped again without %d of them: %d photos (first %d)%s", len(left_out), registered,
                 largest.num_reg_images(), "" if count is None else f", {count} inliers in contradicted pairs")
        if count is not None and count < best_count:
            best, best_count, best_left_out, since_best = again, count, left_out, 0
        elif count is not None or since_best is not None:
            since_best = (since_best or 0) + 1
        if count is not None and count == sum(inliers[p] for p in left_out):
            break  # every pair it was given agrees with it
        if since_best is not None and since_best >= PATIENCE:
            break  # the pairs put back since the best did not make a better model
    log.info("sfm: %s kept (%d inliers in pairs it contradicts)",
             "the first model" if best is first else f"the model without {len(best_left_out)} pairs", best_count)
    if false_pairs is not None:
        false_pairs += described(best_left_out)
    return best


def _largest(models: dict):
    return max(models.values(), key=lambda r: r.num_reg_images())


def left_out_warning(registered: int, photos: int, mapping: Mapping) -> str | None:
    """A warning when the largest model leaves out more than a quarter of the photos: how many, and
    what to try (the global mapper only where it was not tried), or None."""
    if registered >= WARN_REGISTERED_SHARE * photos:
        return None
    tips = ["take more photos, with more overlap between neighbours (round corners especially)",
            "extract more features (features.max_num_features, features.max_image_size)"]
    tried = {a.mapper for a in mapping.attempts}
    tips += [f"sfm.mapper: {other}" for other in ("global", "incremental") if other not in tried]
    return (f"only {registered} of {photos} photos are in the largest model ({photos - registered} left out); "
            f"later stages use that model alone. Try: " + "; ".join(tips))


def incremental_options(cfg, seed: int):
    import pycolmap

    opts = _common_options(pycolmap.IncrementalPipelineOptions(), cfg, seed)
    opts.ba_refine_focal_length = cfg.refine_focal_length
    opts.ba_refine_principal_point = cfg.refine_principal_point
    opts.ba_refine_extra_params = cfg.refine_extra_params
    opts.ba_global_frames_ratio = cfg.ba_global_ratio
    opts.ba_global_points_ratio = cfg.ba_global_ratio
    opts.ba_global_max_num_iterations = cfg.ba_max_iterations
    mapper = opts.mapper
    mapper.init_min_tri_angle = cfg.init_min_tri_angle
    mapper.abs_pose_min_num_inliers = cfg.abs_pose_min_num_inliers
    mapper.ba_local_num_images = cfg.ba_local_images
    mapper.random_seed = seed
    mapper.num_threads = colmap_threads(cfg)
    opts.triangulation.random_seed = seed
    return opts


def _common_options(opts, cfg, seed: int):
    """``opts`` (either mapper's pipeline options) with what both mappers take from ``cfg``."""
    opts.min_num_matches = cfg.min_num_matches
    opts.min_model_size = cfg.min_model_size
    opts.multiple_models = cfg.multiple_models
    opts.random_seed = seed
    opts.num_threads = colmap_threads(cfg)
    return opts


def colmap_threads(cfg) -> int:
    """COLMAP's thread count: all cores, or one where bit-identical re-runs are asked for (Ceres'
    multi-threaded sums, and so the incremental mapper's later decisions, depend on scheduling)."""
    return 1 if cfg.deterministic else -1


#: a refinement the model may not support (principal points, distortion) is kept when it lowers the
#: mean reprojection error by a fraction of at least max(MIN_GAIN, GAIN_OBSERVATIONS / observations). A
#: few more parameters fitted to noise gain about 1 / (2 observations); the bound asks for ~50x that, and
#: 0.2 % at least. Principal points: temple_ring gains 0.58 % over 23,060 observations, fountain_p11
#: 1.9 % over 28,238 (both kept: AUC@5 +10 and +5); 16 synthetic views on an orbit 0.0 % over 9,659, 6
#: of them 0.29 % over 1,536 (refused: their true principal points are the image centres, refined ones
#: drift 4 and 20 px and the poses tilt). Distortion: the zoo's turntable_black (an object in the
#: middle of each photo) gains 0.01 % over 7,295 (refused: its true k1 is 0; refined, k1 -0.03 took the
#: focal length to 568.6 for a true 576, and fused F@0.2 % was .778 against .821 without it)
MIN_GAIN = 0.002
GAIN_OBSERVATIONS = 25.0


def camera_start(database: Path) -> tuple[dict[int, np.ndarray], frozenset[int]]:
    """What :func:`final_bundle_adjustment` compares the cameras with: their starting parameters in
    ``database`` (camera id -> parameters) and the ids of those whose focal length came from EXIF."""
    with read_only(database) as db:
        return stored_camera_params(db), cameras_with_exif_focal(db)


def final_bundle_adjustment(rec, cfg, initial: dict[int, np.ndarray], exif_focal: frozenset[int] = frozenset(),
                            drop_loose: bool = True):
    """The finished model adjusted once more (:func:`_adjust_and_choose`), then rid of the observations
    it leaves more than the mapper's outlier threshold off (and of points left with fewer than two), as
    COLMAP's mapper does after each global BA. Where a refinement is refused, the model adjusted without
    it can leave observations far off that only the refinement explained: on the test suite's 16-view
    scene, with its distortion refused, 4 such observations took one photo's mean error to 4.3 px and the
    model's to 0.51 px (0.17 px without them). ``drop_loose``: whether its loose points go
    (:func:`drop_loose_points`)."""
    rec = _adjust_and_choose(rec, cfg, initial, exif_focal, drop_loose)
    drop_outlier_observations(rec)
    return rec


def drop_outlier_observations(rec) -> None:
    """Delete ``rec``'s observations over the mapper's outlier threshold (:func:`outlier_px`), and the points
    left with fewer than two; logged."""
    import pycolmap

    dropped = pycolmap.ObservationManager(rec).filter_all_points3D(outlier_px(), 0.0)
    if dropped:
        log.info("final BA: %d observations over %g px off dropped", dropped, outlier_px())


#: a point whose track's mean reprojection error exceeds this many times the model's median is loose
#: (:func:`drop_loose_points`)
LOOSE_POINT_FACTOR = 3.0


def drop_loose_points(rec) -> int:
    """Delete the points of ``rec`` whose track's mean reprojection error exceeds LOOSE_POINT_FACTOR times
    the median over its points; how many went.

    COLMAP's mapper drops observations over a fixed 4 px; the robust loss of the final BA only damps those
    under it. Points a few times the median off are most often not one surface point: the highlight of a
    glaze seen from several views (its virtual image moves with the view), a corner of two depths, a
    repeated pattern. Kept, they pull the cameras: in the zoo's glossy scene, the relative rotation
    errors between the cameras had a median of 0.206 degrees, 0.088 with the same scene rendered matte;
    its floor, seen from 1-2 m, then lay 1.4 thresholds off in places and the fused cloud's accuracy fell
    from 97 % to 89 %. Adjusted again without the 3x-median points (232 of 1,906), 0.137 degrees. On 13 of
    the zoo's other 15 scenes the same cut lowered that median by 9-55 % (walkaround 0.281 -> 0.227,
    turntable_black 0.229 -> 0.128, far_field 0.114 -> 0.070); noisy_phone 0.040 -> 0.044 and
    masked_object 0.019 -> 0.021 rose (docs/DECISIONS.md)."""
    rec.update_point_3d_errors()
    errors = {point_id: point.error for point_id, point in rec.points3D.items()}
    if not errors:
        return 0
    cut = LOOSE_POINT_FACTOR * float(np.median(list(errors.values())))
    loose = [point_id for point_id, error in errors.items() if error > cut]
    for point_id in loose:
        rec.delete_point3D(point_id)
    return len(loose)


def outlier_px() -> float:
    """COLMAP's mapper's outlier threshold (``filter_max_reproj_error``, 4 px)."""
    import pycolmap

    return pycolmap.IncrementalMapperOptions().filter_max_reproj_error


def _adjust_and_choose(rec, cfg, initial: dict[int, np.ndarray], exif_focal: frozenset[int] = frozenset(),
                       drop_loose: bool = True):
    """One last global BA over the finished model, with a robust loss, and again without its observations
    over the mapper's outlier threshold and (``drop_loose``) its loose points (:func:`drop_loose_points`). Then two
    refinements that the photos may not constrain, each kept only where it explains the observations
    better (:func:`_explains_better`):

    - distortion (``cfg.refine_extra_params``): the model is adjusted again with each camera's
      distortion held at its ``initial`` value (camera id -> parameters the mapper started from: zero,
      or a calibration's). Where the features cover only the middle of the photos (an object on a
      turntable), distortion trades off against the focal length and fits noise, which bends the
      dense surface;
    - principal points (``cfg.final_refine_principal_point``, unless refined all along): one more BA
      refines them (an orbit at one height leaves them unconstrained: they trade off against the
      cameras' tilt). Where a camera's focal length came from EXIF (camera ids in ``exif_focal``, its
      value in ``initial``), the refinement must also not take the focal length farther from it
      (:func:`_keeps_to_exif_focal`).

    Fisheye and 360 cameras keep both (the synthetic fisheye orbit: refining principal points lowered
    the reprojection error by 0.67 %, and AUC@5 from 96.9 to 85.0). Returns the model kept."""
    import pycolmap

    _bundle_adjust(rec, cfg, cfg.refine_principal_point)
    drop_outlier_observations(rec)  # a wild observation goes, not its point with it
    loose = drop_loose_points(rec) if drop_loose else 0
    if loose:
        log.info("final BA: %d points whose reprojection error exceeds %g times the median dropped; adjusted "
                 "again", loose, LOOSE_POINT_FACTOR)
        _bundle_adjust(rec, cfg, cfg.refine_principal_point)
    if not all(camera.is_perspective_pinhole() for camera in rec.cameras.values()):
        return rec
    if cfg.refine_extra_params and any(len(camera.extra_params_idxs()) for camera in rec.cameras.values()):
        plain = pycolmap.Reconstruction(rec)
        for camera_id, camera in plain.cameras.items():
            params = camera.params.copy()
            extra = camera.extra_params_idxs()
            params[extra] = initial[camera_id][extra] if camera_id in initial else 0.0
            camera.params = params
        held = replace(cfg, refine_extra_params=False)
        _bundle_adjust(plain, held, cfg.refine_principal_point)
        if not _explains_better(plain, rec, "distortion"):
            rec, cfg = plain, held
    if cfg.refine_principal_point or not cfg.final_refine_principal_point:
        return rec
    refined = pycolmap.Reconstruction(rec)
    _bundle_adjust(refined, cfg, True)
    if _explains_better(rec, refined, "principal points") and _keeps_to_exif_focal(rec, refined, initial, exif_focal):
        return refined
    return rec


def _keeps_to_exif_focal(held, refined, initial: dict[int, np.ndarray], exif_focal: frozenset[int]) -> bool:
    """Whether refining the principal points leaves every camera's focal length no farther from its EXIF
    value (``initial``, for the camera ids in ``exif_focal``) than with them held; logged where not.

    Where the photos constrain them weakly, the principal point, the focal length and the cameras'
    tilt and distance trade against one another, and a systematic error of the keypoints can pull the
    refinement along that trade: the zoo's facade_walk refines cy 6 px off its true centre, passing
    :func:`_explains_better`, and the focal length goes 455 -> 464 for a true 448 (EXIF: 444); courtyard
    with 12 photos 432 -> 424 for a true 432 (EXIF: 430), every camera tilted 1.6 degrees. A principal
    point truly off centre, held at the centre, biases the focal length instead, and refining it brings
    the focal length back towards the truth (temple_ring 1553 -> 1533 for 1520, fountain_p11 2978 -> 2758
    for 2759; their photos carry no EXIF focal length, so they are not checked)."""
    for camera_id in exif_focal & set(held.cameras.keys()):
        camera = held.cameras[camera_id]
        idx = list(camera.focal_length_idxs())
        exif = float(np.mean(initial[camera_id][idx]))
        before = float(np.mean(camera.params[idx]))
        after = float(np.mean(refined.cameras[camera_id].params[idx]))
        if abs(after - exif) > abs(before - exif):
            log.info("final BA: principal points left out: refining them takes camera %d's focal length from "
                     "%.1f to %.1f px, farther from its EXIF value (%.1f)", camera_id, before, after, exif)
            return False
    return True


def _explains_better(simpler, fuller, what: str) -> bool:
    """Whether the model ``fuller`` (``simpler`` with ``what`` refined too) lowers the mean
    reprojection error enough (:data:`MIN_GAIN`), each observation's error capped
    (:func:`capped_mean_error`); logged."""
    before = capped_mean_error(simpler)
    after = capped_mean_error(fuller)
    gain = (before - after) / before if before > 0 else 0.0
    keep = gain >= max(MIN_GAIN, GAIN_OBSERVATIONS / max(fuller.compute_num_observations(), 1))
    log.info("final BA: refining %s %s (mean reprojection error %.4f px without, %.4f px with: %.2f %%)", what,
             "lowers the reprojection error enough" if keep else "gains too little: left out", before, after,
             100 * gain)
    return keep


def capped_mean_error(rec) -> float:
    """The mean reprojection error of ``rec``'s observations, each capped at the mapper's outlier
    threshold (:func:`outlier_px`).

    Uncapped, one observation decides: in a zoo masked_object run, a point seen nearly side-on (its
    normalised radius 22) landed inside the photo only through the fold of a refined k1 of -0.002; with
    k1 held at its true 0 it reprojected 9,873 px off, the mean error read 2.05 px against 0.34, and the
    refined distortion was kept. It took the focal length 0.16 % off (575.1 for 576), shifted the dense
    surface up to a pixel in the photos and cost 3 dB of held-out texture PSNR. Capped, the same two
    models read 0.3792 and 0.3790 px (a gain of 0.05 %: left out)."""
    cap = outlier_px()
    total, count = 0.0, 0
    for image in rec.images.values():
        if image.has_pose:
            errors = observation_errors(rec, image)
            total += float(np.minimum(np.nan_to_num(errors, nan=cap), cap).sum())
            count += len(errors)
    return total / count if count else 0.0


def _bundle_adjust(rec, cfg, principal_point: bool) -> None:
    import pycolmap

    pycolmap.bundle_adjustment(rec, ba_options(cfg, principal_point))


def ba_options(cfg, principal_point: bool):
    """The options of a last global bundle adjustment (robust loss; what it refines from ``cfg``)."""
    import pycolmap

    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = cfg.refine_focal_length
    opts.refine_principal_point = principal_point
    opts.refine_extra_params = cfg.refine_extra_params
    opts.print_summary = False
    opts.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    opts.ceres.solver_options.max_num_iterations = cfg.final_ba_iterations
    opts.ceres.solver_options.function_tolerance = 1e-6
    opts.ceres.solver_options.num_threads = colmap_threads(cfg)
    return opts


def registration_report(database: Path, models: list, min_matches: int, init_min_tri_angle: float = 16.0,
                        min_model_size: int = 3, taken_out: dict[str, str] | None = None) -> dict:
    """Per model: registered photos; per unregistered photo: the reason (``taken_out``'s where a photo
    was taken out of the model, else from its verified matches); with no model, ``reason``: what the
    database shows about why (:func:`_no_model_reason`)."""
    import pycolmap

    with read_only(database) as db:
        names = {i: name for name, i in image_ids(db).items()}
        geometries = db.execute("SELECT pair_id, rows, config FROM two_view_geometries").fetchall()
        cameras = db.execute("SELECT width, height, params, prior_focal_length FROM cameras").fetchall()
    partners: dict[int, list[int]] = {i: [] for i in names}
    for pair_id, n, _ in geometries:
        if n >= min_matches:
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            partners[a].append(n)
            partners[b].append(n)
    in_model = {}
    for k, rec in enumerate(models):
        for image_id in rec.reg_image_ids():
            in_model.setdefault(rec.image(image_id).name, k)
    unregistered = {}
    for image_id, name in sorted(names.items(), key=lambda x: x[1]):
        if in_model.get(name) == 0:
            continue
        if name in in_model:
            unregistered[name] = f"registered in separate model {in_model[name]} (no overlap with the largest)"
        elif taken_out and name in taken_out:
            unregistered[name] = taken_out[name]
        elif not partners[image_id]:
            unregistered[name] = f"too few matches: no other photo shares {min_matches}+ verified matches with it"
        else:
            best = max(partners[image_id])
            unregistered[name] = (f"registration failed: {len(partners[image_id])} matched photo(s), best "
                                  f"{best} inliers, but too few 2D-3D correspondences to the model")
    matched = sum(1 for v in partners.values() if v)
    reason = ""
    if not models:
        reason = (_no_start_measured(database, geometries, len(names), init_min_tri_angle, min_model_size)
                  or _no_model_reason(len(names), matched, geometries, cameras, min_matches, init_min_tri_angle))
    return {
        "total_images": len(names),
        "models": [{"registered": rec.num_reg_images(), "points": rec.num_points3D(),
                    "mean_reproj_error": rec.compute_mean_reprojection_error()} for rec in models],
        "unregistered": unregistered,
        "reason": reason,
    }


#: COLMAP's incremental mapper starts from a pair with at least this many verified inliers
#: (IncrementalMapperOptions.init_min_num_inliers)
INIT_MIN_INLIERS = 100
#: ... whose second camera moves less than this along the first's viewing axis (init_max_forward_motion)
INIT_MAX_FORWARD_MOTION = 0.95
#: strong pairs whose two-view pose is estimated to tell why no model was built (each takes milliseconds)
MAX_START_PAIRS_CHECKED = 50


def _no_model_reason(photos: int, matched: int, geometries: list, cameras: list, min_matches: int,
                     init_min_tri_angle: float) -> str:
    """Why no model was built, from what the database shows: too few matches, no pair strong enough
    to start, or strong pairs that still gave no start, with the causes visible for that, most
    telling first: focal priors the pairs' geometry contradicts, pairs that fit a homography, the
    focal lengths the cameras start from, the baseline."""
    import pycolmap

    if matched < 2:
        return (f"Too few matches: no pair of the {photos} photos shares {min_matches}+ verified matches; "
                "are they photos of the same scene with enough overlap?")
    strong = [config for _, n, config in geometries if n >= INIT_MIN_INLIERS]
    if not strong:
        best = max(n for _, n, _ in geometries)
        return (f"No initial pair: {matched} photos have matches, but no pair has the {INIT_MIN_INLIERS}+ verified "
                f"inliers the mapper needs to start (the best has {best}); take photos with more overlap, or "
                "extract more features (features.max_image_size, features.max_num_features)")
    config = pycolmap.TwoViewGeometryConfiguration
    flat = sum(1 for c in strong if c in (config.PLANAR, config.PANORAMIC, config.PLANAR_OR_PANORAMIC))
    uncalibrated = sum(1 for c in strong if c == config.UNCALIBRATED)
    fov, priors = _starting_fov(cameras)
    causes = []
    if priors and 2 * uncalibrated >= len(strong):
        # with focal priors COLMAP calls a pair UNCALIBRATED when the essential matrix they imply
        # explains far fewer matches than a free fundamental matrix
        causes.append(f"wrong focal length priors: {uncalibrated} of those pairs contradict the focal lengths the "
                      f"cameras start from (EXIF or calibration: {fov} degree field of view across the diagonal); "
                      "a cropped, resized or digitally zoomed photo keeps a focal length that no longer fits it: "
                      "check the photos' EXIF")
    if flat:
        causes.append(f"{flat} of those pairs fit a homography (the camera turned on the spot, or the scene is "
                      "one plane): take photos from positions further apart")
    if priors and not causes:
        causes.append(f"wrong focal length priors ({priors} of {len(cameras)} camera(s) start from EXIF or a "
                      f"calibration: {fov} degree field of view across the diagonal): check the photos' EXIF")
    elif not priors:
        causes.append(f"no EXIF focal length: the cameras start from a guess ({fov} degree field of view across "
                      "the diagonal, ingest.default_focal_factor) that may be far off: a calibration helps")
    causes.append(f"too little baseline between the overlapping photos: lower sfm.init_min_tri_angle "
                  f"(now {init_min_tri_angle:g} degrees)")
    return (f"No initial pair: {len(strong)} pair(s) have the {INIT_MIN_INLIERS}+ verified inliers the mapper needs "
            f"to start, but none of them gave a first two-view model with a {init_min_tri_angle:g} degree "
            f"triangulation angle. Likely causes: " + "; ".join(causes) + ".")


def _no_start_measured(database: Path, geometries: list, photos: int, init_min_tri_angle: float,
                       min_model_size: int) -> str | None:
    """Why no model, where the strong pairs show the mapper could start: it estimates each pair's
    two-view pose as COLMAP's mapper does to start (:data:`INIT_MIN_INLIERS` inliers, less than
    :data:`INIT_MAX_FORWARD_MOTION` forward motion, ``init_min_tri_angle``). A pair that passes made a
    first two-view model, so what failed is that no model grew to ``min_model_size`` photos; None where
    no pair passes (the start itself failed: :func:`_no_model_reason`)."""
    import pycolmap

    strong = sorted(((n, pair_id) for pair_id, n, _ in geometries if n >= INIT_MIN_INLIERS), reverse=True)
    if not strong:
        return None
    started = []
    with private_copy(database) as copy, opened(copy) as db:
        names = {image.image_id: image.name for image in db.read_all_images()}
        for _, pair_id in strong[:MAX_START_PAIRS_CHECKED]:
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            geometry = db.read_two_view_geometry(a, b)
            ka, kb = (np.asarray(db.read_keypoints(i), np.float64) for i in (a, b))
            if ka.ndim != 2 or kb.ndim != 2 or (geometry.inlier_matches.max(0) >= [len(ka), len(kb)]).any():
                continue  # no keypoints stored for these inliers: nothing to measure
            ok = pycolmap.estimate_two_view_geometry_pose(
                db.read_camera(db.read_image(a).camera_id), ka[:, :2].copy(),
                db.read_camera(db.read_image(b).camera_id), kb[:, :2].copy(), geometry)
            if ok and len(geometry.inlier_matches) >= INIT_MIN_INLIERS \
                    and abs(geometry.cam2_from_cam1.translation[2]) < INIT_MAX_FORWARD_MOTION \
                    and np.degrees(geometry.tri_angle) > init_min_tri_angle:
                started.append((names[a], names[b], float(np.degrees(geometry.tri_angle))))
    if not started:
        return None
    a, b, angle = started[0]
    if photos < min_model_size:
        return (f"Only {photos} photos: the mapper can start from {a} and {b} ({angle:.0f} degree triangulation "
                f"angle), but a model needs sfm.min_model_size ({min_model_size}) photos; add photos or lower it")
    return (f"No model grew to sfm.min_model_size ({min_model_size}) photos: {len(started)} of the strongest pairs "
            f"could start one (e.g. {a} and {b}, {angle:.0f} degree triangulation angle), but no other photo shared "
            "enough points with them to register (sfm.abs_pose_min_num_inliers 2D-3D matches); take photos with "
            "more overlap, extract more features, or try sfm.mapper: global")


def _starting_fov(cameras: list) -> tuple[str, int]:
    """The diagonal field of view (degrees, one value or a range) of the focal lengths the database's
    cameras start from, and how many of them are priors (EXIF or calibration), not guesses."""
    fovs, priors = [], 0
    for width, height, params, prior in cameras:
        focal = float(np.frombuffer(params, dtype=np.float64)[0])
        fovs.append(float(np.degrees(2 * np.arctan2(np.hypot(width, height) / 2, focal))))
        priors += bool(prior)
    span = f"{min(fovs):.0f}" if max(fovs) - min(fovs) < 1 else f"{min(fovs):.0f} to {max(fovs):.0f}"
    return span, priors
