"""matching: choose image pairs, match their SIFT features and verify them geometrically (COLMAP)."""

from __future__ import annotations

import errno
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from recon.options import opt
from recon.sparse import pairs as pairing
from recon.sparse.database import opened
from recon.stage import Progress, Stage, StageContext, register
from recon.workspace import read_json


@dataclass(frozen=True)
class MatchingConfig:
    method: Literal["auto", "exhaustive", "sequential", "retrieval"] = opt(
        "auto", "pair selection; auto = sequential for video frames, else exhaustive up to `exhaustive_max` "
                "photos, else retrieval")
    exhaustive_max: int = opt(40, "auto: largest photo count matched exhaustively", ge=2)
    overlap: int = opt(10, "sequential: match each frame with this many following frames", ge=1)
    loop_detection: bool = opt(True, "sequential: also match frames that look alike (loop closure)")
    loop_neighbors: int = opt(5, "sequential: loop-closure candidates per frame", ge=0)
    neighbors: int = opt(15, "retrieval: most similar photos matched with each photo", ge=1)
    vocabulary_words: int = opt(64, "retrieval: words of the VLAD vocabulary learned from the photos", ge=8)
    max_ratio: float = opt(0.8, "Lowe's ratio test threshold", gt=0, le=1)
    max_distance: float = opt(0.7, "largest descriptor distance of a match", gt=0, le=1)
    cross_check: bool = opt(True, "keep only mutual best matches")
    max_error: float = opt(4.0, "RANSAC inlier threshold in pixels for geometric verification", gt=0)
    min_inliers: int = opt(15, "fewest inlier matches for a verified pair", ge=5)
    guided_matching: bool = opt(False, "re-match guided by the estimated two-view geometry (slower)")
    chunk_pairs: int = opt(250, "pairs matched per chunk (progress and resume granularity)", ge=1,
                           affects_output=False)


def _options(cfg: MatchingConfig, seed: int):
    import pycolmap

    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = -1
    mo.guided_matching = cfg.guided_matching
    mo.sift.max_ratio = cfg.max_ratio
    mo.sift.max_distance = cfg.max_distance
    mo.sift.cross_check = cfg.cross_check
    vo = pycolmap.TwoViewGeometryOptions()
    vo.min_num_inliers = cfg.min_inliers
    vo.ransac.max_error = cfg.max_error
    vo.ransac.random_seed = seed
    return mo, vo


def choose_pairs(cfg: MatchingConfig, database: Path, names: list[str], seed: int,
                 ordered: bool = False) -> tuple[str, list]:
    """The method actually used and the pairs (indices into ``names``) to match.

    ``ordered``: the images are frames in capture order (a video), so ``auto`` matches sequentially.
    """
    n = len(names)
    method = cfg.method
    if method == "auto":
        method = "sequential" if ordered else "exhaustive" if n <= cfg.exhaustive_max else "retrieval"
    if method == "exhaustive":
        return method, pairing.exhaustive_pairs(n)
    similarity = _similarity(database, names, cfg.vocabulary_words, seed)
    if method == "retrieval":
        return method, pairing.retrieval_pairs(similarity, cfg.neighbors)
    found = set(pairing.sequential_pairs(n, cfg.overlap))
    if cfg.loop_detection and cfg.loop_neighbors:
        found.update(pairing.loop_pairs(similarity, cfg.overlap, cfg.loop_neighbors))
    return method, sorted(found)


def _similarity(database: Path, names: list[str], words: int, seed: int):
    with opened(database) as db:
        by_name = {img.name: img.image_id for img in db.read_all_images()}
        descs = [db.read_descriptors(by_name[name]).data for name in names]
    g = pairing.global_descriptors(descs, words=words, seed=seed)
    return g @ g.T


@register
class Matching(Stage):
    name = "matching"
    version = 1
    Config = MatchingConfig
    requires = ("features",)
    outputs = ("database.db", "pairs.txt")
    publish = {"database.db": "database.db"}
    uses_seed = True
    summary = "pair selection, SIFT matching and geometric verification into database.db"

    def run(self, ctx: StageContext, cfg: MatchingConfig) -> dict:

        database = ctx.out / "database.db"
        if database.exists():  # an interrupted run's database: COLMAP skips the pairs already in it
            _set_names(database, _names_by_id(ctx.input("features") / "database.db"))  # aliases of a kill
            with opened(database) as db:
                ctx.log.info("matching: %d pairs already done, resuming", db.num_matched_image_pairs())
        else:
            tmp = ctx.out / ".database.db.copy"
            shutil.copyfile(ctx.input("features") / "database.db", tmp)
            tmp.replace(database)
        names = _names(database)
        listing = read_json(ctx.input("features") / "images.json") or {}
        method, pairs = choose_pairs(cfg, database, names, ctx.seed, bool(listing.get("ordered")))
        mo, vo = _options(cfg, ctx.seed)
        _match_pairs(ctx, database, [(names[i], names[j]) for i, j in pairs], mo, vo, cfg.chunk_pairs)
        with opened(database) as db:
            matched = db.num_matched_image_pairs()
        verified = sum(1 for v in _inlier_counts(database) if v >= cfg.min_inliers)
        ctx.log.info("matching: %s, %d pairs matched, %d verified", method, matched, verified)
        return {"method": method, "pairs": matched, "verified_pairs": verified}


def _match_pairs(ctx: StageContext, database: Path, named: list[tuple[str, str]], mo, vo, chunk: int) -> None:
    import pycolmap

    (ctx.out / "pairs.txt").write_text("".join(f"{a} {b}\n" for a, b in named))
    progress = Progress(ctx.log, "matching pairs", len(named))
    names = _names_by_id(database)
    # COLMAP reads a pair list as "name1 name2" lines split at spaces ('#' starts a comment): photos
    # named so go by an alias while matching; no photo is named like it (ingest skips hidden paths)
    alias = {name: f".recon-alias/{i}" if name.startswith("#") or any(c.isspace() for c in name) else name
             for i, name in names.items()}
    with opened(database) as db:
        keypoints = {name: db.num_keypoints_for_image(i) for i, name in names.items()}
    _set_names(database, {i: alias[name] for i, name in names.items()})
    try:
        for start in range(0, len(named), chunk):
            part = named[start:start + chunk]
            _check_space(ctx, database, part, keypoints)
            listing = ctx.out / ".chunk.txt"
            listing.write_text("".join(f"{alias[a]} {alias[b]}\n" for a, b in part))
            po = pycolmap.ImportedPairingOptions()
            po.match_list_path = str(listing)
            # COLMAP skips pairs already in the database, so a resumed run continues where it stopped
            pycolmap.match_image_pairs(str(database), mo, po, vo, device=pycolmap.Device.cpu)
            progress.advance(len(part))
    finally:
        _set_names(database, names)
    (ctx.out / ".chunk.txt").unlink(missing_ok=True)


def _check_space(ctx: StageContext, database: Path, part: list[tuple[str, str]], keypoints: dict[str, int]) -> None:
    """Refuse to match ``part`` unless the disk can hold what COLMAP may write for it: on a full disk
    COLMAP's matcher threads abort the whole process. Bound: raw and verified matches of 8 bytes,
    at most the smaller keypoint count of a pair each, doubled for SQLite's journal, plus 4 MiB."""
    need = 2 * sum(16 * min(keypoints[a], keypoints[b]) for a, b in part) + (4 << 20)
    free = shutil.disk_usage(database.parent).free
    if free < need:
        ctx.log.warning("matching: the next %d pairs may need %.0f MB; %.1f MB are free", len(part),
                        need / 1e6, free / 1e6)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(database.parent))


def _names_by_id(database: Path) -> dict[int, str]:
    with opened(database) as db:
        return {img.image_id: img.name for img in db.read_all_images()}


def _set_names(database: Path, names: dict[int, str]) -> None:
    """Rename the database's images to ``names`` (image id -> name) where they differ."""
    with opened(database) as db:
        for image in db.read_all_images():
            if image.name != names[image.image_id]:
                image.name = names[image.image_id]
                db.update_image(image)


def _inlier_counts(database: Path) -> list[int]:
    with opened(database) as db:
        _, geometries = db.read_two_view_geometries()
        return [len(g.inlier_matches) for g in geometries]


def _names(database: Path) -> list[str]:
    with opened(database) as db:
        return sorted(img.name for img in db.read_all_images())
