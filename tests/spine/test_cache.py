"""The stage cache: unchanged config runs nothing; one changed option re-runs exactly what depends on it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pycolmap

import recon
from recon.files import read_json

REPO = Path(__file__).resolve().parents[2]
SPARSE = REPO / "tests" / "sparse_test.yaml"


def stage_runs(ws: Path) -> dict[str, int]:
    """How many completed outputs each stage has in the cache (from their manifests)."""
    cache = ws / ".recon" / "cache"
    return {d.name: len(list(d.glob("*/manifest.json"))) for d in cache.iterdir()}


def test_unchanged_config_runs_nothing(copy_workspace, small_scene):
    before = stage_runs(copy_workspace)
    proc = subprocess.run([sys.executable, "-m", "recon.cli", "run", str(SPARSE), "--images",
                           str(small_scene / "images"), "--workspace", str(copy_workspace)],
                          capture_output=True, text=True, check=True)
    assert "ran nothing (all cached)" in proc.stdout
    assert stage_runs(copy_workspace) == before


def test_matching_option_reruns_matching_and_what_follows(copy_workspace, small_scene):
    result = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace),
                       matching={"max_ratio": 0.75})
    assert result.ran == ["matching", "sfm", "export"]
    assert result.cached == ["ingest", "calibrate", "preprocess", "features"]
    runs = stage_runs(copy_workspace)
    assert runs["ingest"] == 1 and runs["features"] == 1
    assert runs["matching"] == 2 and runs["sfm"] == 2 and runs["export"] == 2
    manifest = read_json(next((copy_workspace / ".recon/cache/matching").glob("*/manifest.json")))
    assert manifest["stage"] == "matching" and "pycolmap" in manifest["versions"]
    # the published model is the new one, and switching back costs nothing
    again = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace))
    assert again.ran == []
    assert pycolmap.Reconstruction(str(copy_workspace / "sparse" / "0")).num_reg_images() == 16


def test_status_says_what_is_stale_and_why(copy_workspace, small_scene):
    rows = {r.name: r for r in recon.api.status(SPARSE, overrides=["sfm.ba_local_images=8"],
                                                 images=str(small_scene / "images"),
                                                 workspace=str(copy_workspace))}
    assert [rows[n].state for n in ("ingest", "features", "matching")] == ["done"] * 3
    assert rows["sfm"].state == "stale" and "sfm.ba_local_images: 6 -> 8" in rows["sfm"].why
    assert rows["export"].state == "stale" and "upstream changed: sfm" in rows["export"].why
    proc = subprocess.run([sys.executable, "-m", "recon.cli", "status", str(copy_workspace)],
                          capture_output=True, text=True, check=True)
    assert all(line.split()[1] == "done" for line in proc.stdout.strip().splitlines())


def test_changed_photo_invalidates_ingest(tmp_path, small_scene):
    import shutil

    images = tmp_path / "images"
    shutil.copytree(small_scene / "images", images)
    ws = tmp_path / "ws"
    first = recon.run({"until": "features"}, images=str(images), workspace=str(ws))
    assert first.ran == ["ingest", "calibrate", "preprocess", "features"]
    data = bytearray((images / "view_003.jpg").read_bytes())
    data[len(data) // 2] ^= 0x01  # same name and size, other content
    (images / "view_003.jpg").write_bytes(bytes(data))
    rows = {r.name: r for r in recon.api.status({"until": "features"}, images=str(images), workspace=str(ws))}
    assert rows["ingest"].state == "stale" and rows["ingest"].why == "input files changed"


def test_second_run_on_a_workspace_in_use_is_refused(copy_workspace, small_scene):
    from recon.workspace import Workspace, WorkspaceError

    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from recon.workspace import Workspace\n"
        f"with Workspace({str(copy_workspace)!r}).locked():\n"
        "    print('locked', flush=True); time.sleep(30)\n")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        try:
            with Workspace(copy_workspace).locked():
                raise AssertionError("lock was not exclusive")
        except WorkspaceError as exc:
            assert f"in use by pid {holder.pid}" in str(exc)
    finally:
        holder.kill()
        holder.wait()
    with Workspace(copy_workspace).locked():  # a killed holder leaves no stale lock
        pass


def test_rerun_stage_hides_outputs_made_from_its_old_output(copy_workspace, small_scene):
    """After sfm re-runs with --until sfm, export's files (made from the old model) leave the workspace."""
    assert (copy_workspace / "points.ply").exists()
    result = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace),
                       until="sfm", sfm={"ba_local_images": 8})
    assert result.ran == ["sfm"]
    assert not (copy_workspace / "points.ply").exists() and not (copy_workspace / "transforms.json").exists()
    assert (copy_workspace / "sparse" / "0" / "images.bin").exists()
    again = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace),
                      sfm={"ba_local_images": 8})
    assert again.ran == ["export"] and (copy_workspace / "points.ply").exists()
