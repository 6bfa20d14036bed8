"""matching: choose image pairs, match their SIFT features and verify them geometrically (COLMAP)."""

from __future__ import annotations

import dataclasses
import errno
import os
import shutil
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from recon.items import ItemStore, item_key
from recon.options import opt
from recon.products import FeatureDatabase, MatchDatabase
from recon.sparse import pairs as pairing
from recon.sparse.database import image_ids, opened, read_camera, read_descriptors, read_only
from recon.sparse.georeference import gps_sigma
from recon.sparse.matcher import Block, BlockError, PairOptions, match_block, read_block, write_block
from recon.stage import Stage, StageContext, register

#: auto: the least share of photos with a GPS tag for spatial matching
AUTO_SPATIAL_SHARE = 0.8


@dataclass(frozen=True)
class MatchingConfig:
    method: Literal["auto", "exhaustive", "sequential", "retrieval", "spatial"] = opt(
        "auto", "pair selection; auto = sequential for video frames, else exhaustive up to `exhaustive_max` "
                "photos, else spatial when 80 % of the photos have GPS and lie farther from their "
                "`spatial_neighbors`th nearest than twice its accuracy, else retrieval")
    exhaustive_max: int = opt(40, "auto: largest photo count matched exhaustively", ge=2)
    overlap: int = opt(10, "sequential: match each frame with this many following frames", ge=1)
    loop_detection: bool = opt(True, "sequential: also match frames that look alike (loop closure)")
    loop_neighbors: int = opt(5, "sequential: loop-closure candidates per frame", ge=0)
    neighbors: int = opt(15, "retrieval: most similar photos matched with each photo", ge=1)
    vocabulary_words: int = opt(64, "retrieval: words of the VLAD vocabulary learned from the photos", ge=8)
    spatial_neighbors: int = opt(12, "spatial: nearest photos by GPS position matched with each photo", ge=1)
    spatial_max_distance: float = opt(0.0, "spatial: farthest GPS distance of a pair, metres (0: no limit)",
                                      ge=0)
    spatial_retrieval: int = opt(3, "spatial: most similar photos (by appearance) also matched with each photo; "
                                    "a photo without GPS gets `neighbors` of them", ge=0)
    max_ratio: float = opt(0.8, "Lowe's ratio test threshold", gt=0, le=1)
    max_distance: float = opt(0.7, "largest descriptor distance of a match", gt=0, le=1)
    cross_check: bool = opt(True, "keep only mutual best matches")
    max_error: float = opt(4.0, "RANSAC inlier threshold in pixels for geometric verification", gt=0)
    min_inliers: int = opt(15, "fewest inlier matches for a verified pair", ge=5)
    guided_matching: bool = opt(False, "re-match guided by the estimated two-view geometry (slower)")
    chunk_pairs: int = opt(50, "most pairs per task: a block matched by one worker (the unit of resume)", ge=1,
                           affects_output=False)


def pair_options(cfg: MatchingConfig, seed: int, num_threads: int = 1) -> PairOptions:
    return PairOptions(max_ratio=cfg.max_ratio, max_distance=cfg.max_distance, cross_check=cfg.cross_check,
                       guided_matching=cfg.guided_matching, max_error=cfg.max_error, min_inliers=cfg.min_inliers,
                       seed=seed, num_threads=num_threads)


def choose_pairs(cfg: MatchingConfig, database: Path, names: list[str], seed: int,
                 listing: dict) -> tuple[str, str, list]:
    """The method actually used, why (for ``auto``) and the pairs (indices into ``names``) to match.

    ``listing``: ingest's photo listing, for the photos' GPS tags and whether they are frames in
    capture order (a video: ``auto`` matches sequentially).
    """
    n = len(names)
    images = listing.get("images", [])
    positions = pairing.gps_positions(images, names)
    method, why = cfg.method, ""
    if method == "auto":
        method, why = auto_method(cfg, n, bool(listing.get("ordered")), positions, images)
    if method == "exhaustive":
        return method, why, pairing.exhaustive_pairs(n)
    if method == "spatial":
        needs_similarity = cfg.spatial_retrieval or not np.isfinite(positions).all()
        similarity = image_similarity(database, names, cfg.vocabulary_words, seed) if needs_similarity else None
        return method, why, pairing.spatial_matching_pairs(positions, similarity, cfg.spatial_neighbors,
                                                           cfg.spatial_max_distance, cfg.neighbors,
                                                           cfg.spatial_retrieval)
    similarity = image_similarity(database, names, cfg.vocabulary_words, seed)
    if method == "retrieval":
        return method, why, pairing.retrieval_pairs(similarity, cfg.neighbors)
    found = set(pairing.sequential_pairs(n, cfg.overlap))
    if cfg.loop_detection and cfg.loop_neighbors:
        found.update(pairing.loop_pairs(similarity, cfg.overlap, cfg.loop_neighbors))
    return method, why, sorted(found)


def auto_method(cfg: MatchingConfig, n: int, ordered: bool, positions: np.ndarray,
                images: list[dict]) -> tuple[str, str]:
    """``auto``'s method for ``n`` photos and why. Spatial needs GPS on most photos, and the photos it
    would pair farther apart than their GPS accuracy (twice the median): around a small object, GPS
    noise alone would decide which photos are "nearest"."""
    if ordered:
        return "sequential", "the photos are video frames"
    if n <= cfg.exhaustive_max:
        return "exhaustive", f"{n} photos, at most exhaustive_max = {cfg.exhaustive_max}"
    tagged = int(np.isfinite(positions).all(axis=1).sum())
    if tagged < AUTO_SPATIAL_SHARE * n:
        return "retrieval", f"{tagged} of {n} photos have GPS (spatial needs {AUTO_SPATIAL_SHARE:.0%})"
    spacing = pairing.neighbor_distance(positions, cfg.spatial_neighbors)
    accuracy = float(np.median([gps_sigma(img["gps"], 0.0) for img in images if img.get("gps")]))
    if spacing <= 2 * accuracy:
        return "retrieval", (f"the photos' GPS positions are {spacing:.1f} m from their {cfg.spatial_neighbors}th "
                             f"nearest, within twice their accuracy ({accuracy:.1f} m)")
    return "spatial", f"{tagged} of {n} photos have GPS"


def image_similarity(database: Path, names: list[str], words: int, seed: int):
    """Cosine similarity (n x n) of the photos' VLAD descriptors, over a vocabulary learned from them."""
    with read_only(database) as db:
        by_name = image_ids(db)
        descs = [read_descriptors(db, by_name[name]) for name in names]
    g = pairing.global_descriptors(descs, words=words, seed=seed)
    return g @ g.T


@register
class Matching(Stage):
    name = "matching"
    version = 2
    Config = MatchingConfig
    requires = (FeatureDatabase,)
    produces = MatchDatabase
    uses_seed = True
    summary = "pair selection, SIFT matching and geometric verification into database.db"

    def run(self, ctx: StageContext, cfg: MatchingConfig) -> dict:
        upstream = ctx.input(FeatureDatabase)
        features = upstream.database
        with read_only(features) as db:
            ids = image_ids(db)
        names = sorted(ids)
        method, why, pairs = choose_pairs(cfg, features, names, ctx.seed, upstream.listing())
        if why:
            ctx.log.info("matching: auto chose %s: %s", method, why)
        named = [(names[i], names[j]) for i, j in pairs]
        ctx.output.pairs.write_text("".join(f"{a} {b}\n" for a, b in named))
        id_pairs = [(ids[a], ids[b]) for a, b in named]
        store = ItemStore(ctx.workspace.items_dir(self.name), ".npz")
        keys = dict(zip(id_pairs, pair_keys(cfg, ctx.seed, upstream, named)))
        folder = ctx.out / "blocks"
        done = _finished_pairs(folder, ctx)
        stored = {pair: path for pair in id_pairs if ctx.reuse and pair not in done
                  and (path := store.get(keys[pair])) is not None}
        todo = [pair for pair in id_pairs if pair not in done and pair not in stored]
        if done:
            ctx.log.info("matching: %d pairs already done, resuming", len(done))
        if stored:
            ctx.log.info("matching: %d of %d pairs reused from earlier runs", len(stored), len(id_pairs))
        ctx.map(match_block, _blocks(todo, features, folder, cfg, ctx), desc="matching pairs",
                done=lambda b: Path(b.out).exists(), size=lambda b: len(b.pairs))
        results = _stored_results(stored)
        for path in sorted(folder.glob("*.npz")):
            for pair, (matches, geometry) in read_block(path).items():
                results[pair] = matches, geometry
                store.write(keys[pair], lambda tmp, p=pair: write_block(tmp, [(*p, *results[p])]))
        database = ctx.output.database
        _write_database(features, results, id_pairs, database)
        with opened(database) as db:
            matched = db.num_matched_image_pairs()
        verified = sum(1 for v in _inlier_counts(database) if v >= cfg.min_inliers)
        shutil.rmtree(folder, ignore_errors=True)
        ctx.log.info("matching: %s, %d pairs matched, %d verified", method, matched, verified)
        return {"method": method, "pairs": matched, "verified_pairs": verified, "reused_pairs": len(stored),
                "matched_pairs": len(id_pairs) - len(stored)}


    def reusable(self, ctx: StageContext, cfg: MatchingConfig) -> str:
        upstream = ctx.input(FeatureDatabase)
        with read_only(upstream.database) as db:
            names = sorted(image_ids(db))
        method, _, pairs = choose_pairs(cfg, upstream.database, names, ctx.seed, upstream.listing())
        keys = pair_keys(cfg, ctx.seed, upstream, [(names[i], names[j]) for i, j in pairs])
        store = ItemStore(ctx.workspace.items_dir(self.name), ".npz")
        return f"reuses {sum(store.get(k) is not None for k in keys)} of {len(keys)} pairs ({method})"


def pair_keys(cfg: MatchingConfig, seed: int, features: FeatureDatabase, named: list[tuple[str, str]]) -> list[str]:
    """The key of each pair's verified matches in the item store (:mod:`recon.items`): both photos'
    features (their own item keys), both cameras (verification uses the intrinsics and whether the
    focal length is a prior) and the options matching and verification depend on; nothing about
    the other photos, so the pairs of a set grown by new photos keep their keys."""
    options = dataclasses.asdict(pair_options(cfg, seed))
    del options["num_threads"]  # how the work is split, not its result
    features_keys = features.item_keys()
    with read_only(features.database) as db:
        ids = image_ids(db)
        cameras = {}
        for name in {n for pair in named for n in pair}:
            camera = read_camera(db, ids[name])
            cameras[name] = [camera.model.name, camera.width, camera.height, camera.params.tolist(),
                             camera.has_prior_focal_length]
    return [item_key({"item": "verified_pair", "version": Matching.version, "options": options,
                      "features": [features_keys[a], features_keys[b]], "cameras": [cameras[a], cameras[b]]})
            for a, b in named]


def _stored_results(stored: dict[tuple[int, int], Path]) -> dict[tuple[int, int], tuple]:
    """The matches and geometry of pairs found in the item store, under this run's image and camera
    ids (an item keeps the ids of the run that made it)."""
    results = {}
    for pair, path in stored.items():
        (matches, geometry), = read_block(path).values()
        results[pair] = matches, geometry
    return results


def _blocks(pairs: list[tuple[int, int]], features: Path, folder: Path, cfg: MatchingConfig,
            ctx: StageContext) -> list[Block]:
    """Tasks of at most ``cfg.chunk_pairs`` pairs, at least four per worker (so workers end together)."""
    cores = len(os.sched_getaffinity(0))
    workers = max(1, min(ctx.executor.workers, cores))
    options = pair_options(cfg, ctx.seed, max(1, cores // workers))
    chunk = max(1, min(cfg.chunk_pairs, -(-len(pairs) // (4 * workers))))
    blocks = []
    for start in range(0, len(pairs), chunk):
        part = tuple(pairs[start:start + chunk])
        tag = zlib.crc32(repr(part).encode())  # names differ for different pairs, whatever the chunk size
        blocks.append(Block(str(features), part, options, str(folder / f"{start:07d}-{tag:08x}.npz")))
    return blocks


def _finished_pairs(folder: Path, ctx: StageContext) -> set[tuple[int, int]]:
    """Pairs in the block files a stopped run left; a file that is not a block (truncated, or put
    there by someone else: it is read as data, never run) is removed and its pairs matched again."""
    done = set()
    for path in sorted(folder.glob("*.npz")):
        try:
            done.update(read_block(path))
        except BlockError as exc:
            ctx.log.warning("matching: %s; matching its pairs again", exc)
            path.unlink()
    return done


def _write_database(features: Path, results: dict[tuple[int, int], tuple], pairs: list[tuple[int, int]],
                    database: Path) -> None:
    """The features database with the matches and geometries of ``pairs``, in that order; written
    by this process alone.

    The disk is checked first: SQLite on a full disk is an error COLMAP does not recover from. Bound:
    the matches' size, twice (SQLite's journal), plus the database and 4 MiB."""
    matches = sum(m.nbytes + g.inlier_matches.nbytes + 512 for m, g in results.values())
    need = 2 * matches + features.stat().st_size + (4 << 20)
    if shutil.disk_usage(database.parent).free < need:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(database.parent))
    tmp = database.with_name(".database.db.tmp")
    shutil.copyfile(features, tmp)
    with opened(tmp) as db:
        for pair in pairs:
            matches, geometry = results[pair]
            db.write_matches(*pair, matches)
            db.write_two_view_geometry(*pair, geometry)
    tmp.replace(database)


def _inlier_counts(database: Path) -> list[int]:
    with opened(database) as db:
        _, geometries = db.read_two_view_geometries()
        return [len(g.inlier_matches) for g in geometries]


