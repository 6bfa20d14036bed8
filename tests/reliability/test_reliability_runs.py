"""Runs that stop early: Ctrl-C or a kill in every stage, a full disk, an upgraded stage. Each keeps
what was computed and the run that follows finishes with the same result."""

from __future__ import annotations

import contextlib
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from reliability_checks import (
    INTERRUPTED,
    SPARSE,
    SPARSE_STAGES,
    assert_one_line_error,
    assert_same_reconstruction,
    cache_dir,
    cli,
    complete_outputs,
    ctrl_c_reaches_it,
    partial_outputs,
)

import recon
from recon.files import read_json
from recon.stage import REGISTRY

DRIVER = Path(__file__).with_name("interrupt.py")
INTERRUPTED_STAGES = ["ingest", "features", "matching", "sfm", "export"]


def run_args(scene: Path, ws: Path) -> list[str]:
    return ["run", str(SPARSE), "--images", str(scene / "images"), "--workspace", str(ws),
            "-o", "matching.chunk_pairs=10"]


def interrupted_run(stage: str, signal_name: str, args: list[str]) -> subprocess.CompletedProcess:
    """recon run with ``signal_name`` sent inside ``stage`` (see interrupt.py); its own session, so
    that a SIGINT to its process group reaches recon and its workers but not pytest."""
    return subprocess.run([sys.executable, str(DRIVER), stage, signal_name, *args], capture_output=True, text=True,
                          timeout=300, start_new_session=True, preexec_fn=ctrl_c_reaches_it)


def manifest_times(ws: Path) -> dict[str, list[float]]:
    return {s: [read_json(p / "manifest.json")["finished"] for p in complete_outputs(ws, s)] for s in SPARSE_STAGES}


@pytest.mark.parametrize("signal_name", ["SIGINT", pytest.param("SIGKILL", marks=pytest.mark.slow)])
def test_stop_in_every_stage_then_rerun_gives_the_same_model(signal_name, small_scene, sparse_workspace, tmp_path):
    """One workspace, stopped once inside each stage in turn; each run resumes the stage the one
    before stopped in, keeps every finished stage and item, and the last run completes with the
    same model as an uninterrupted run. (Quick SIGKILL variants: below for ingest, sfm and export,
    tests/spine/test_resume.py for features and matching.)"""
    ws = tmp_path / "ws"
    args = run_args(small_scene, ws)
    finished: dict[str, list[float]] = {}
    for k, stage in enumerate(INTERRUPTED_STAGES):
        proc = interrupted_run(stage, signal_name, args)
        assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
        if signal_name == "SIGINT":
            assert proc.returncode == 130, proc.stderr[-3000:]
            assert proc.stderr.strip().splitlines()[-1] == INTERRUPTED
        else:
            assert proc.returncode == -9, proc.stderr[-3000:]
        # the stage stopped in is not taken for complete; its partial output is kept for the next run
        assert complete_outputs(ws, stage) == [] and len(partial_outputs(ws, stage)) == 1
        done = SPARSE_STAGES[: SPARSE_STAGES.index(stage)]
        assert all(len(complete_outputs(ws, s)) == 1 for s in done), proc.stderr[-3000:]
        # what earlier runs completed was not computed again
        now = manifest_times(ws)
        assert all(now[s] == finished[s] for s in finished)
        finished = {s: now[s] for s in done}
        if stage == "features":
            assert len(list(partial_outputs(ws, "features")[0].glob("features/*.npz"))) >= 4
        if k and INTERRUPTED_STAGES[k - 1] in ("features", "matching"):  # per-item resume
            what = {"features": r"features: (\d+) of 16 already done", "matching": r"matching: (\d+) pairs already done"}
            resumed = re.search(what[INTERRUPTED_STAGES[k - 1]], proc.stderr)
            assert resumed and int(resumed[1]) >= {"features": 4, "matching": 20}[INTERRUPTED_STAGES[k - 1]]
    last = cli(*args)
    assert last.returncode == 0, last.stderr[-3000:]
    assert last.stdout.startswith("recon: ran export;")
    now = manifest_times(ws)
    assert {s: now[s] for s in finished} == finished
    assert all(partial_outputs(ws, s) == [] for s in SPARSE_STAGES)
    assert_same_reconstruction(ws, sparse_workspace)


@pytest.mark.parametrize("stage", ["ingest", "sfm", "export"])
def test_sigkill_in_a_stage_then_rerun_gives_the_same_model(stage, copy_workspace, sparse_workspace, small_scene):
    """Quick variants of the SIGKILL chain: a finished workspace loses ``stage``'s output and the
    outputs after it (ingest: its own only: an ingest that gives the same output, as checked here,
    keeps the later stages' keys), is killed inside ``stage`` and run again."""
    ws = copy_workspace
    later = [stage] if stage == "ingest" else SPARSE_STAGES[SPARSE_STAGES.index(stage):]
    for name in later:
        shutil.rmtree(cache_dir(ws, name))
    before = manifest_times(ws)
    args = run_args(small_scene, ws)
    killed = interrupted_run(stage, "SIGKILL", args)
    assert killed.returncode == -9, killed.stderr[-3000:]
    assert complete_outputs(ws, stage) == [] and len(partial_outputs(ws, stage)) == 1
    again = cli(*args)
    assert again.returncode == 0, again.stderr[-3000:]
    assert again.stdout.startswith(f"recon: ran {', '.join(later)};")
    now = manifest_times(ws)
    assert {s: now[s] for s in SPARSE_STAGES if s not in later} == {s: before[s] for s in SPARSE_STAGES if s not in later}
    assert all(partial_outputs(ws, s) == [] for s in SPARSE_STAGES)
    for name in later:
        output, = complete_outputs(ws, name)
        original, = complete_outputs(sparse_workspace, name)
        assert sorted(p.relative_to(output) for p in output.rglob("*")) == \
            sorted(p.relative_to(original) for p in original.rglob("*"))
        assert read_json(output / "manifest.json")["key"] == read_json(original / "manifest.json")["key"]
    assert read_json(complete_outputs(ws, "ingest")[0] / "images.json") == \
        read_json(complete_outputs(sparse_workspace, "ingest")[0] / "images.json")
    assert_same_reconstruction(ws, sparse_workspace)


# ---------------------------------------------------------------------------------------------
# A full disk


@contextlib.contextmanager
def small_disk(path: Path, size: int):
    """A tmpfs of ``size`` bytes mounted at ``path`` (needs root); unmounted afterwards."""
    path.mkdir(parents=True, exist_ok=True)
    if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                      capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root): the full-disk test is skipped")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=True)


def resize(path: Path, size: int) -> None:
    subprocess.run(["mount", "-o", f"remount,size={size}", str(path)], check=True)


@pytest.mark.parametrize("stage", ["matching", "sfm"])
def test_full_disk_keeps_the_last_complete_stage_and_says_so(stage, small_scene, sparse_workspace, tmp_path):
    """The workspace's disk fills up in ``stage`` (its earlier stages copied from a finished run):
    one line says so and names the last complete stage, which is intact; once space is freed (sfm),
    the same command finishes with the same model. matching meets a disk too small for its next pairs
    (COLMAP's matcher would abort the process when SQLite hits a full disk); sfm fills it while
    COLMAP writes the model (which COLMAP does not notice: the truncated model must not be taken
    for complete)."""
    with small_disk(tmp_path / "disk", 64 << 20) as disk:
        ws = disk / "ws"
        (ws / ".recon" / "cache").mkdir(parents=True)
        before = SPARSE_STAGES[: SPARSE_STAGES.index(stage)]
        for name in before:
            shutil.copytree(cache_dir(sparse_workspace, name), cache_dir(ws, name), symlinks=True)
        used = shutil.disk_usage(disk).used
        free = {"matching": 256 << 10, "sfm": 160 << 10}[stage]
        resize(disk, used + free)
        args = run_args(small_scene, ws)
        full = cli(*args)
        message = assert_one_line_error(full, f"{stage}: the disk holding {ws} is full (")
        assert message.endswith(f"completed stages are kept (last: {before[-1]}): free some space and run the "
                                "same command again to resume")
        assert complete_outputs(ws, stage) == []
        for name in before:  # the completed stages are intact
            kept, = complete_outputs(ws, name)
            original, = complete_outputs(sparse_workspace, name)
            assert sorted(p.name for p in kept.rglob("*")) == sorted(p.name for p in original.rglob("*"))
            assert read_json(kept / "manifest.json") == read_json(original / "manifest.json")
        if stage == "matching":  # COLMAP has not touched the database: the resumed run is a plain one
            assert complete_outputs(ws, "matching") == [] and len(partial_outputs(ws, "matching")) == 1
            return
        resize(disk, 64 << 20)
        again = cli(*args)
        assert again.returncode == 0, again.stderr[-3000:]
        assert again.stdout.startswith(f"recon: ran {stage}")
        assert_same_reconstruction(ws, sparse_workspace)


# ---------------------------------------------------------------------------------------------
# Stage versions


def test_upgraded_stage_invalidates_only_its_cache_and_what_follows(copy_workspace, small_scene, monkeypatch):
    """A new version of sfm re-runs sfm and the stage after it; the stages before it stay cached,
    and the old sfm output stays in the cache (going back to the old version costs nothing)."""
    sfm = type(REGISTRY["sfm"])
    monkeypatch.setattr(sfm, "version", sfm.version + 1)
    rows = {r.name: r for r in recon.api.status(SPARSE, images=str(small_scene / "images"),
                                                 workspace=str(copy_workspace))}
    assert rows["sfm"].state == "stale" and rows["sfm"].why == f"stage version {sfm.version - 1} -> {sfm.version}"
    assert [rows[s].state for s in ("ingest", "features", "matching")] == ["done"] * 3
    assert rows["export"].why == "upstream changed: sfm"
    before = manifest_times(copy_workspace)
    result = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace))
    assert result.ran == ["sfm", "export"]
    assert result.cached == ["ingest", "calibrate", "preprocess", "features", "matching"]
    after = manifest_times(copy_workspace)
    assert all(after[s] == before[s] for s in result.cached)
    assert len(after["sfm"]) == 2 and len(after["export"]) == 2
    monkeypatch.undo()
    assert recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace)).ran == []
