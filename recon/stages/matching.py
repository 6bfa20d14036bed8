"""matching: choose image pairs, match their SIFT features and verify them geometrically (COLMAP)."""

from __future__ import annotations

import errno
import os
import shutil
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from recon.options import opt
from recon.products import FeatureDatabase, MatchDatabase
from recon.sparse import pairs as pairing
from recon.sparse.database import image_ids, opened, read_descriptors, read_only
from recon.sparse.matcher import Block, BlockError, PairOptions, match_block, read_block
from recon.stage import Stage, StageContext, register


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
    chunk_pairs: int = opt(50, "most pairs per task: a block matched by one worker (the unit of resume)", ge=1,
                           affects_output=False)


def pair_options(cfg: MatchingConfig, seed: int, num_threads: int = 1) -> PairOptions:
    return PairOptions(max_ratio=cfg.max_ratio, max_distance=cfg.max_distance, cross_check=cfg.cross_check,
                       guided_matching=cfg.guided_matching, max_error=cfg.max_error, min_inliers=cfg.min_inliers,
                       seed=seed, num_threads=num_threads)


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
    similarity = image_similarity(database, names, cfg.vocabulary_words, seed)
    if method == "retrieval":
        return method, pairing.retrieval_pairs(similarity, cfg.neighbors)
    found = set(pairing.sequential_pairs(n, cfg.overlap))
    if cfg.loop_detection and cfg.loop_neighbors:
        found.update(pairing.loop_pairs(similarity, cfg.overlap, cfg.loop_neighbors))
    return method, sorted(found)


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
        listing = upstream.listing()
        method, pairs = choose_pairs(cfg, features, names, ctx.seed, bool(listing.get("ordered")))
        named = [(names[i], names[j]) for i, j in pairs]
        ctx.output.pairs.write_text("".join(f"{a} {b}\n" for a, b in named))
        id_pairs = [(ids[a], ids[b]) for a, b in named]
        folder = ctx.out / "blocks"
        done = _finished_pairs(folder, ctx)
        todo = [pair for pair in id_pairs if pair not in done]
        if done:
            ctx.log.info("matching: %d pairs already done, resuming", len(id_pairs) - len(todo))
        ctx.map(match_block, _blocks(todo, features, folder, cfg, ctx), desc="matching pairs",
                done=lambda b: Path(b.out).exists(), size=lambda b: len(b.pairs))
        database = ctx.output.database
        _write_database(features, folder, id_pairs, database)
        with opened(database) as db:
            matched = db.num_matched_image_pairs()
        verified = sum(1 for v in _inlier_counts(database) if v >= cfg.min_inliers)
        shutil.rmtree(folder)
        ctx.log.info("matching: %s, %d pairs matched, %d verified", method, matched, verified)
        return {"method": method, "pairs": matched, "verified_pairs": verified}


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


def _write_database(features: Path, folder: Path, pairs: list[tuple[int, int]], database: Path) -> None:
    """The features database with the matches and geometries of ``pairs``, in that order, from the
    block files in ``folder``; written by this process alone.

    The disk is checked first: SQLite on a full disk is an error COLMAP does not recover from. Bound:
    the blocks' size, twice (SQLite's journal), plus the database and 4 MiB."""
    files = sorted(folder.glob("*.npz"))
    need = 2 * sum(f.stat().st_size for f in files) + features.stat().st_size + (4 << 20)
    if shutil.disk_usage(database.parent).free < need:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(database.parent))
    results = {}
    for path in files:
        results.update(read_block(path))
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


