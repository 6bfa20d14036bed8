"""Depth maps per view in the item store (issue 18): an mvs option recomputes every depth map and
nothing before mvs; maps whose inputs did not change are reused, byte for byte."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import recon
from recon.files import read_json

REPO = Path(__file__).resolve().parents[2]
SPARSE = REPO / "tests" / "sparse_test.yaml"
# small and quick: depth-map quality is measured by tests/mvs and the benchmarks
MVS = {"max_image_size": 120, "pyramid_levels": 1, "iterations": 2}
BEFORE_MVS = ("ingest", "preprocess", "features", "matching", "sfm", "undistort")


def manifests(ws: Path, stage: str) -> list[dict]:
    """The manifests of every completed output of ``stage``, oldest first."""
    found = [read_json(p) for p in (ws / ".recon" / "cache" / stage).glob("*/manifest.json")]
    return sorted(found, key=lambda m: m["finished"])


def depth_maps(ws: Path, manifest: dict) -> dict[str, Path]:
    folder = ws / ".recon" / "cache" / "mvs" / manifest["key"][:16] / "stereo" / "depth_maps"
    return {p.name: p for p in folder.glob("*.geometric.bin")}


def run_mvs(ws: Path, scene: Path, **mvs) -> recon.pipeline.RunResult:
    return recon.run(SPARSE, overrides=["until=mvs"], images=str(scene / "images"), workspace=str(ws), executor="serial",
                     undistort={"max_image_size": 240}, mvs={**MVS, **mvs})


@pytest.fixture(scope="module")
def mvs_workspace(sparse_workspace, small_scene, tmp_path_factory) -> Path:
    """The sparse test workspace taken through undistort and mvs (16 views, quick settings)."""
    ws = tmp_path_factory.mktemp("mvs-reuse") / "ws"
    shutil.copytree(sparse_workspace, ws, symlinks=True)
    run_mvs(ws, small_scene)
    return ws


def test_a_window_radius_change_recomputes_every_depth_map_and_nothing_before_mvs(mvs_workspace, small_scene,
                                                                                   tmp_path):
    ws = tmp_path / "ws"
    shutil.copytree(mvs_workspace, ws, symlinks=True)
    (first,) = manifests(ws, "mvs")
    result = run_mvs(ws, small_scene, window_radius=3)
    assert result.ran == ["mvs"] and set(BEFORE_MVS) <= set(result.cached)
    for stage in BEFORE_MVS:
        assert len(manifests(ws, stage)) == 1, stage
    first, second = manifests(ws, "mvs")
    assert second["config"]["window_radius"] == 3
    s = second["summary"]
    assert (s["reused"], s["computed"], s["photometric_computed"]) == (0, 16, 16)
    before, after = depth_maps(ws, first), depth_maps(ws, second)
    assert sorted(before) == sorted(after) and len(after) == 16
    assert all(after[n].read_bytes() != before[n].read_bytes() for n in after)  # every map made again


def test_an_option_only_the_final_maps_read_reuses_every_photometric_map(mvs_workspace, small_scene, tmp_path):
    """The filter's options and ``planar_fill`` act after the photometric pass (reuse.FINAL_ONLY): the
    final maps are made again from the stored photometric maps, and they change."""
    ws = tmp_path / "ws"
    shutil.copytree(mvs_workspace, ws, symlinks=True)
    (first,) = manifests(ws, "mvs")
    result = run_mvs(ws, small_scene, filter_max_cost=0.3)
    assert result.ran == ["mvs"]
    s = result.summaries["mvs"]
    assert (s["reused"], s["computed"], s["photometric_computed"], s["photometric_reused"]) == (0, 16, 0, 16)
    before, after = depth_maps(ws, first), depth_maps(ws, manifests(ws, "mvs")[1])
    assert sum(after[n].read_bytes() != before[n].read_bytes() for n in after) >= 8


def test_a_new_final_version_makes_the_final_maps_again_from_the_stored_photometric_ones(mvs_workspace, small_scene,
                                                                                        tmp_path, monkeypatch):
    """A change to the filter or the fill (reuse.FINAL_VERSION, with the stage's version) makes every final
    map again, not the photometric maps; each view keeps the sources the earlier version's output gave it
    (here one view's, shortened by one, which it keeps and makes its photometric maps for)."""
    import json

    from recon.mvs import reuse
    from recon.stages.mvs import VIEWS, Mvs

    ws = tmp_path / "ws"
    shutil.copytree(mvs_workspace, ws, symlinks=True)
    (first,) = manifests(ws, "mvs")
    record = ws / ".recon" / "cache" / "mvs" / first["key"][:16] / VIEWS
    views = json.loads(record.read_text())
    name = next(n for n, v in sorted(views.items()) if len(v["sources"]) >= 3)
    views[name]["sources"] = views[name]["sources"][:-1]
    record.write_text(json.dumps(views))
    monkeypatch.setattr(reuse, "FINAL_VERSION", reuse.FINAL_VERSION + 1)
    monkeypatch.setattr(Mvs, "version", Mvs.version + 1)
    result = run_mvs(ws, small_scene)
    assert result.ran == ["mvs"]
    s = result.summaries["mvs"]
    assert (s["reused"], s["computed"], s["photometric_computed"], s["photometric_reused"]) == (0, 16, 1, 15)
    again = json.loads((ws / ".recon" / "cache" / "mvs" / manifests(ws, "mvs")[1]["key"][:16] / VIEWS).read_text())
    assert again[name]["sources"] == views[name]["sources"]


def test_depth_maps_are_reused_when_nothing_they_depend_on_changed(mvs_workspace, small_scene, tmp_path):
    """The mvs output lost, the same config runs mvs again: every view's maps come from the item
    store (``recon status`` says so first), identical to those the first run computed."""
    ws = tmp_path / "ws"
    shutil.copytree(mvs_workspace, ws, symlinks=True)
    (first,) = manifests(ws, "mvs")
    kept = {n: p.read_bytes() for n, p in depth_maps(ws, first).items()}
    shutil.rmtree(ws / ".recon" / "cache" / "mvs" / first["key"][:16])
    overrides = ["until=mvs", "undistort.max_image_size=240", *(f"mvs.{k}={v}" for k, v in MVS.items())]
    rows = {r.name: r for r in recon.api.status(SPARSE, overrides, images=str(small_scene / "images"),
                                                 workspace=str(ws))}
    assert rows["mvs"].reuse == "reuses the depth maps of 16 of 16 views"
    result = run_mvs(ws, small_scene)
    assert result.ran == ["mvs"]
    s = result.summaries["mvs"]
    assert (s["reused"], s["computed"], s["photometric_computed"]) == (16, 0, 0)
    (again,) = manifests(ws, "mvs")
    assert {n: p.read_bytes() for n, p in depth_maps(ws, again).items()} == kept


def test_a_forced_mvs_reuses_no_depth_map(mvs_workspace, small_scene, tmp_path):
    """Neither the final maps nor the photometric ones come from the item store (the photometric maps
    did: a forced run kept an earlier run's depth ranges and seeds)."""
    ws = tmp_path / "ws"
    shutil.copytree(mvs_workspace, ws, symlinks=True)
    result = recon.run(SPARSE, overrides=["until=mvs"], images=str(small_scene / "images"), workspace=str(ws),
                       executor="serial", force=["mvs"], undistort={"max_image_size": 240}, mvs=MVS)
    s = result.summaries["mvs"]
    assert (s["reused"], s["computed"], s["photometric_computed"], s["photometric_reused"]) == (0, 16, 16, 0)


def _twelve_then_sixteen(small_scene, tmp_path, reselect_top: int):
    """12 photos to depth maps, then the 4 others added and the same command run again: the second
    run's summaries, its views.json, the photos added, the first run's final depth maps (bytes)
    and the second run's."""
    images, ws = tmp_path / "images", tmp_path / "ws"
    images.mkdir()
    photos = sorted((small_scene / "images").iterdir())
    for photo in photos[:12]:
        shutil.copy(photo, images)
    first = recon.run(SPARSE, overrides=["until=mvs"], images=str(images), workspace=str(ws), executor="serial",
                      undistort={"max_image_size": 240}, mvs={**MVS, "reselect_top": reselect_top})
    assert first.summaries["mvs"]["computed"] == 12
    (before,) = manifests(ws, "mvs")
    kept = {n: p.read_bytes() for n, p in depth_maps(ws, before).items()}
    for photo in photos[12:]:
        shutil.copy(photo, images)
    result = recon.run(SPARSE, overrides=["until=mvs"], images=str(images), workspace=str(ws), executor="serial",
                       undistort={"max_image_size": 240}, mvs={**MVS, "reselect_top": reselect_top})
    assert result.summaries["sfm"]["mapping"] == "continued" and result.summaries["sfm"]["registered"] == 16
    _, after = manifests(ws, "mvs")
    views = read_json(ws / ".recon" / "cache" / "mvs" / after["key"][:16] / "views.json")
    return result.summaries["mvs"], views, [p.name for p in photos[12:]], kept, depth_maps(ws, after)


@pytest.mark.slow
def test_added_photos_cost_their_own_depth_maps(small_scene, tmp_path):
    """sfm keeps the 12 poses, the 12 views keep their sources (``reselect_top: 0``: even where a new
    view now ranks among their best), so their maps are reused (the same files) and only the new
    views' maps are computed."""
    s, views, added, kept, maps = _twelve_then_sixteen(small_scene, tmp_path, reselect_top=0)
    assert s["views"] == 16 and s["reused"] + s["computed"] == 16 and s["reused"] >= 10, s
    assert not any(views[n]["reused"] for n in added)
    reused = [n for n, v in views.items() if v["reused"]]
    assert all(maps[f"{n}.geometric.bin"].read_bytes() == kept[f"{n}.geometric.bin"] for n in reused)


@pytest.mark.slow
def test_views_with_new_sources_rerun_only_the_geometric_pass(small_scene, tmp_path):
    """With ``reselect_top`` 8, a view whose best sources a new photo changes takes them
    but starts from the photometric maps its earlier ones gave: the photometric pass runs for the new
    photos only, and those views' final maps are new files."""
    s, views, added, kept, maps = _twelve_then_sixteen(small_scene, tmp_path, reselect_top=8)
    changed = [n for n, v in views.items() if not v["reused"] and n not in added]
    assert changed and s["photometric_computed"] == len(added) and s["photometric_reused"] == len(changed), s
    assert all(views[n]["photometric_reused"] and set(added) & set(views[n]["sources"]) for n in changed)
    assert not any(views[n]["photometric_reused"] for n in added)
    assert all(maps[f"{n}.geometric.bin"].read_bytes() != kept[f"{n}.geometric.bin"] for n in changed)
