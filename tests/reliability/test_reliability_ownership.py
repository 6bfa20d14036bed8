"""Whose files are whose: recon never replaces, deletes or fingerprints what it did not write.

Each test is a case a user met (issue 13): COLMAP's usual layout (photos in ``proj/images``,
workspace ``proj``) deleted the photos; a user's ``sparse/``, ``database.db`` or ``points.ply`` in a
workspace was deleted; a FIFO named ``x.jpg`` hung the run; dangling links, link loops, unreadable
photos and non-UTF-8 names ended in internal errors; a workspace inside the photo folder took its
own outputs for photos, so every identical re-run redid everything.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from reliability_checks import SPARSE, assert_one_line_error, cli

from recon.sparse.photos import list_photos
from recon.workspace import SMALL_FILE


def tree_digest(folder: Path) -> dict[str, str]:
    """Relative path -> SHA-256 of every regular file under ``folder`` (links not followed)."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and not p.is_symlink()}


@pytest.fixture(scope="module")
def colmap_layout(small_scene, tmp_path_factory):
    """COLMAP's layout (photos in proj/images, workspace proj) with hostile entries among the photos,
    run once through the sparse pipeline: (project, photo digests before, the finished run)."""
    proj = tmp_path_factory.mktemp("colmap") / "proj"
    images = proj / "images"
    shutil.copytree(small_scene / "images", images)
    os.mkfifo(images / "x.jpg")  # reading it would block forever
    os.symlink("/dev/zero", images / "zero.jpg")  # a device: endless
    os.symlink(images / "absent.jpg", images / "dangling.jpg")
    os.symlink("loop.jpg", images / "loop.jpg")
    before = tree_digest(images)
    proc = cli("run", SPARSE, "--images", images, "--workspace", proj, timeout=240)
    return proj, before, proc


def test_colmap_layout_keeps_the_photos_and_publishes_the_model(colmap_layout):
    proj, before, proc = colmap_layout
    assert proc.returncode == 0, proc.stderr[-2000:]
    images = proj / "images"
    assert images.is_dir() and not images.is_symlink()
    assert tree_digest(images) == before  # every photo byte-identical, nothing added or removed
    assert (images / "x.jpg").exists() and os.path.islink(images / "loop.jpg")
    assert (proj / "sparse" / "0" / "images.bin").is_file() and (proj / "database.db").is_file()
    assert "is the photo folder: left as it is" in (proj / ".recon" / "recon.log").read_text()


def test_fifo_device_dangling_link_and_loop_are_skipped_with_a_warning(colmap_layout):
    proj, _, proc = colmap_layout
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr
    for name, why in [("x.jpg", "not a regular file"), ("zero.jpg", "not a regular file"),
                      ("dangling.jpg", "dangling symbolic link"), ("loop.jpg", "symbolic link loop")]:
        assert f"{name}: {why}" in proc.stderr, (name, proc.stderr[-2000:])


def test_user_files_in_the_workspace_stop_the_run_before_any_work(small_scene, tmp_path):
    ws = tmp_path / "proj"
    (ws / "sparse" / "0").mkdir(parents=True)
    (ws / "sparse" / "0" / "cameras.txt").write_text("# the user's own COLMAP model\n")
    (ws / "database.db").write_bytes(b"the user's database")
    (ws / "points.ply").write_bytes(b"ply\nthe user's points\n")
    before = tree_digest(ws)
    proc = cli("run", SPARSE, "--images", small_scene / "images", "--workspace", ws)
    line = assert_one_line_error(proc, str(ws / "database.db"))  # the first in pipeline order
    assert "recon did not make it" in line and "--workspace" in line
    assert "2 more: sparse, points.ply" in line
    assert {k: v for k, v in tree_digest(ws).items() if not k.startswith(".recon/")} == before
    assert not list((ws / ".recon").glob("cache/*/*")), "no stage may run"


def test_a_user_file_where_a_folder_must_go_is_a_clash(small_scene, tmp_path):
    ws = tmp_path / "ws"
    ws.mkdir()
    (ws / "dense").write_text("a file of the user's named like recon's dense folder")
    proc = cli("run", SPARSE, "--images", small_scene / "images", "--workspace", ws, "-o", "until=fusion")
    assert_one_line_error(proc, str(ws / "dense"))
    assert (ws / "dense").read_text().startswith("a file of the user's")


@pytest.mark.parametrize("where", ["inside", "same"])
def test_workspace_in_the_photo_folder_never_fingerprints_its_outputs(small_scene, tmp_path, where):
    photos = tmp_path / "photos"
    shutil.copytree(small_scene / "images", photos)
    ws = photos / "out" if where == "inside" else photos
    first = cli("run", SPARSE, "--images", photos, "--workspace", ws, timeout=240)
    assert first.returncode == 0, first.stderr[-2000:]
    assert (ws / "points.ply").exists()
    again = cli("run", SPARSE, "--images", photos, "--workspace", ws)
    assert "ran nothing (all cached)" in again.stdout, again.stdout + again.stderr[-2000:]
    cache = ws / ".recon" / "cache" / "ingest"
    assert len([d for d in cache.iterdir() if not d.name.endswith(".partial")]) == 1


def test_non_utf8_name_and_unreadable_photo_are_skipped(small_scene, tmp_path, monkeypatch):
    """In one process (the catalogue's way): the warnings name the files, nothing crashes."""
    photos = tmp_path / "photos"
    shutil.copytree(small_scene / "images", photos)
    odd = os.fsencode(photos) + b"/caf\xe9.jpg"  # Latin-1, not UTF-8
    shutil.copyfile(photos / "view_000.jpg", odd)
    (photos / "locked.jpg").write_bytes((photos / "view_001.jpg").read_bytes())
    real_access = os.access  # root reads everything: play a user who cannot read locked.jpg
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: not str(p).endswith("locked.jpg")
                        and real_access(p, mode, **kw))
    listing = list_photos(photos)
    monkeypatch.undo()
    reasons = {p.name: why for p, why in listing.unreadable}
    assert reasons["locked.jpg"] == "cannot be read (permission denied)"
    assert [why for name, why in reasons.items() if name.startswith("caf")] == [
        "file name is not valid UTF-8; rename the file"]
    assert len(listing.photos) == 16
    proc = cli("run", SPARSE, "--images", photos, "--workspace", tmp_path / "ws", "-o", "stages=[ingest]")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert "caf\\udce9.jpg: file name is not valid UTF-8" in proc.stderr or \
        "caf\\xe9.jpg: file name is not valid UTF-8" in proc.stderr, proc.stderr[-2000:]


def test_a_photo_swapped_with_the_same_size_and_mtime_is_read_again(small_scene, tmp_path):
    photos = tmp_path / "photos"
    shutil.copytree(small_scene / "images", photos)
    ws = tmp_path / "ws"
    args = ["run", SPARSE, "--images", photos, "--workspace", ws, "-o", "stages=[ingest]"]
    assert cli(*args).returncode == 0
    target = photos / "view_003.jpg"
    st = target.stat()
    data = bytearray(target.read_bytes())
    data[-100] ^= 0xFF  # same size, other content (inside the JPEG's entropy-coded data)
    target.write_bytes(bytes(data))
    os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns))  # and the same mtime
    status = cli("status", ws)
    assert "ingest" in status.stdout and "input files changed" in status.stdout, status.stdout
    again = cli(*args)
    assert "ran ingest" in again.stdout, again.stdout


def test_damaged_cached_outputs_are_stale_with_the_reason_and_recomputed(copy_workspace, small_scene):
    ws = copy_workspace
    keys = json.loads((ws / ".recon" / "state.json").read_text())
    matching = ws / ".recon" / "cache" / "matching" / keys["matching"][:16]
    with open(matching / "database.db", "r+b") as f:  # truncate the cached database
        f.truncate(4096)
    sfm = ws / ".recon" / "cache" / "sfm" / keys["sfm"][:16]
    (sfm / "sparse" / "0" / "points3D.bin").unlink()  # and delete a file of the model
    status = cli("status", ws)
    rows = {line.split()[0]: line for line in status.stdout.splitlines()}
    assert "stale" in rows["matching"] and "database.db changed since it was written" in rows["matching"]
    assert "stale" in rows["sfm"] and "sparse/0/points3D.bin was deleted since it was written" in rows["sfm"]
    proc = cli("run", SPARSE, "--images", small_scene / "images", "--workspace", ws, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "ran matching, sfm" in proc.stdout, proc.stdout
    assert "internal error" not in proc.stderr
    assert (ws / "sparse" / "0" / "points3D.bin").is_file()
    assert all(line.split()[1] == "done" for line in cli("status", ws).stdout.splitlines())


def test_verify_checks_every_byte(copy_workspace):
    ws = copy_workspace
    db = (ws / "database.db").resolve()
    st = db.stat()
    with open(db, "r+b") as f:  # same size, same mtime: only a full check sees it
        f.seek(st.st_size // 2)
        byte = f.read(1)
        f.seek(st.st_size // 2)
        f.write(bytes([byte[0] ^ 0xFF]))
    os.utime(db, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert "database.db" not in cli("status", ws).stdout
    assert "database.db changed since it was written (content)" in cli("status", ws, "--verify").stdout


def test_status_after_a_killed_first_run_shows_where_to_resume(small_scene, tmp_path):
    ws = tmp_path / "ws"
    args = ["run", SPARSE, "--images", small_scene / "images", "--workspace", ws]
    killed = subprocess.run([sys.executable, str(Path(__file__).with_name("interrupt.py")), "features", "SIGKILL",
                             *map(str, args)], capture_output=True, text=True, timeout=300, start_new_session=True)
    assert killed.returncode == -9, killed.stderr[-2000:]
    proc = cli("status", ws)
    assert proc.returncode == 0, proc.stderr
    rows = dict(line.split()[:2] for line in proc.stdout.splitlines())
    assert rows["preprocess"] == "done" and rows["features"] == "missing", proc.stdout


def test_home_and_variables_in_config_paths_are_expanded(small_scene, tmp_path, monkeypatch):
    home = tmp_path / "home"
    shutil.copytree(small_scene / "images", home / "photos")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("RECON_TEST_OUT", str(tmp_path / "out"))
    config = tmp_path / "c.yaml"
    config.write_text("images: ~/photos\nworkspace: $RECON_TEST_OUT/ws\nstages: [ingest]\n")
    proc = cli("run", config, env={**os.environ})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "out" / "ws" / "images").is_symlink()
    assert not (tmp_path / "~").exists() and not (tmp_path / "$RECON_TEST_OUT").exists()


def test_a_corrupted_model_file_is_caught_even_with_its_size_and_mtime(copy_workspace):
    """A file up to SMALL_FILE is hashed at every check (a larger one, such as the small scene's images.bin,
    only when its mtime moved or with --verify)."""
    keys = json.loads((copy_workspace / ".recon" / "state.json").read_text())
    cameras_bin = copy_workspace / ".recon" / "cache" / "sfm" / keys["sfm"][:16] / "sparse" / "0" / "cameras.bin"
    st = cameras_bin.stat()
    assert st.st_size <= SMALL_FILE
    data = bytearray(cameras_bin.read_bytes())
    data[len(data) // 2] ^= 0xFF
    cameras_bin.write_bytes(bytes(data))
    os.utime(cameras_bin, ns=(st.st_atime_ns, st.st_mtime_ns))
    rows = {line.split()[0]: line for line in cli("status", copy_workspace).stdout.splitlines()}
    assert "stale" in rows["sfm"] and "sparse/0/cameras.bin changed since it was written (content)" in rows["sfm"]
