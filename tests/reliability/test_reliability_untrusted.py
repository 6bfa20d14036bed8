"""A workspace may come from someone else (a shared file system, an unpacked archive): what recon
reads back from it is data, never code. The matching stage's block files, read on resume, used to be
pickles: whoever could write the workspace ran code as the next user."""

from __future__ import annotations

import os
import pickle
import re
import shutil
from pathlib import Path

import pycolmap
from reliability_checks import SPARSE, cli, complete_outputs, database_rows

from recon.sparse.database import opened
from recon.sparse.matcher import write_block


class RunsCode:
    """Unpickling this makes the folder ``marker``: what a hostile block file would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.mkdir, (self.marker,)


def finished_blocks(database: Path, blocks: Path, leave_out: int) -> None:
    """Block files for all but the first ``leave_out`` pairs of a finished database (a stopped run's
    work, so that the test matches only a few pairs itself)."""
    copy = shutil.copy(database, blocks.parent / "copy.db")  # pycolmap writes to the databases it opens
    with opened(copy) as db:
        pair_ids, geometries = db.read_two_view_geometries()
        results = []
        for pair_id, geometry in sorted(zip(pair_ids, geometries), key=lambda p: p[0])[leave_out:]:
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            results.append((a, b, db.read_matches(a, b), geometry))
    Path(copy).unlink()
    for start in range(0, len(results), 10):
        write_block(blocks / f"done-{start:03d}.npz", results[start:start + 10])


def test_a_planted_block_file_is_not_run_and_its_pairs_are_matched_again(copy_workspace, sparse_workspace,
                                                                          small_scene, tmp_path):
    """Hostile files in the folder a stopped matching run resumes from, under the current block name
    and the old one: nothing in them runs, the stage says which file it ignored, matches the pairs
    no genuine block holds and writes the same database as a clean run."""
    marker = tmp_path / "pwned"
    matching, = complete_outputs(copy_workspace, "matching")
    blocks = matching.with_name(matching.name + ".partial") / "blocks"
    blocks.mkdir(parents=True)
    payload = pickle.dumps([(1, 2, RunsCode(marker), RunsCode(marker))])
    for name in ("0000000-00000000.npz", "0000000-00000000.pkl"):
        (blocks / name).write_bytes(payload)
    finished_blocks(sparse_workspace / "database.db", blocks, leave_out=6)
    proc = cli("run", SPARSE, "--images", small_scene / "images", "--workspace", copy_workspace,
               "--force", "matching", "--until", "matching")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert not marker.exists()
    assert "matching: 0000000-00000000.npz is not a block of matches" in proc.stderr
    resumed = re.search(r"matching: (\d+) pairs already done, resuming", proc.stderr)
    assert resumed and 0 < int(resumed[1]) <= 114  # the genuine blocks (pairs COLMAP reads back)
    assert database_rows(copy_workspace / "database.db") == database_rows(sparse_workspace / "database.db")
