"""Scale benchmarks, two sections of 300 synthetic views each.

``dask`` (issue 8): the seeded scene through features, matching, sfm and mvs on a Dask cluster of
one, then two, worker processes.

Per stage it prints the wall time with 1 and 2 workers and the peak memory (resident set of this
process and all its children, the workers included, sampled every 0.2 s); for matching, the pairs
matched against the exhaustive count and how the retrieval pair count grows with the number of
images (pairs / n and pairs / (n log2 n) on the first n views); and the reconstruction's registered
views and AUC against the scene's ground truth. sfm runs once (in this process, COLMAP's threads).

``spatial`` (issue 16): an aerial survey with GPS tags (recon.synth.survey: 12 flight lines, 3 m of
GPS noise) through the sparse pipeline with ``matching.method`` retrieval, then spatial: pairs and
pairs per view, matching and sfm seconds, registered views and AUC against the ground truth, and the
pairs each method picks among the first n views.

    python -m recon.bench --only scale [--out DIR]      (or: python -m recon.scale_bench [--section S])
"""

from __future__ import annotations

import argparse
import json
import math
import threading
import time
from pathlib import Path

import psutil

import recon
import recon.api

REPO = Path(__file__).resolve().parents[1]
VIEWS = 300


class PeakMemory:
    """Largest resident memory of this process plus its children while the block runs, in bytes."""

    def __init__(self, every: float = 0.2):
        self.every, self.peak = every, 0
        self._stop = threading.Event()

    def _sample(self) -> None:
        me = psutil.Process()
        while not self._stop.is_set():
            total = 0
            for proc in [me, *me.children(recursive=True)]:
                try:
                    total += proc.memory_info().rss
                except psutil.Error:
                    pass
            self.peak = max(self.peak, total)
            self._stop.wait(self.every)

    def __enter__(self) -> PeakMemory:
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def run_stage(scene: Path, ws: Path, stage: str, workers: int, force: bool) -> tuple[float, int, dict]:
    """Run the pipeline up to ``stage`` on ``workers`` Dask workers; (seconds of the stage, peak bytes, summary)."""
    with PeakMemory() as memory:
        result = recon.run(REPO / "pipelines" / "full.yaml", images=str(scene / "images"), workspace=str(ws),
                           until=stage, force=[stage] if force else [], executor=f"dask-local:{workers}",
                           overrides={"mvs.max_image_size": 320})
    return result.seconds.get(stage, 0.0), memory.peak, result.summaries.get(stage, {})


def pair_growth(ws: Path, neighbors: int, words: int, seed: int = 0) -> list[tuple[int, int]]:
    """Retrieval pairs chosen among the first n views, for a few n up to all of them."""
    from recon.sparse import pairs as pairing
    from recon.stages.matching import image_similarity

    database = ws / "database.db"
    names = sorted(p.name for p in (ws / "images").iterdir())
    similarity = image_similarity(database, names, words, seed)
    sizes = sorted({len(names) // 6, len(names) // 3, 2 * len(names) // 3, len(names)})
    return [(n, len(pairing.retrieval_pairs(similarity[:n, :n], neighbors))) for n in sizes]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m recon.scale_bench")
    parser.add_argument("--out", type=Path, default=REPO / "bench_out" / "scale")
    parser.add_argument("--views", type=int, default=VIEWS)
    parser.add_argument("--section", choices=["dask", "spatial"], default=None, help="one section (default: both)")
    args = parser.parse_args(argv)
    if args.section in (None, "spatial"):
        spatial_section(args.out / "survey", args.out / "survey_ws", args.views)
    if args.section in (None, "dask"):
        dask_section(args.out / "scene", args.out / "ws", args.views)
    return 0


def dask_section(scene: Path, ws: Path, views: int) -> None:
    from recon.stages.matching import MatchingConfig
    from recon.synth import render_scene

    if not (scene / "gt" / "scene.json").exists():
        start = time.perf_counter()
        render_scene(scene, views=views, width=640, height=480, seed=0)
        print(f"rendered {views} views in {time.perf_counter() - start:.0f} s", flush=True)
    rows = {}
    for workers in (1, 2):
        for stage in ("features", "matching", "sfm", "mvs"):
            if stage == "sfm" and workers == 2:
                continue
            seconds, peak, summary = run_stage(scene, ws, stage, workers, force=workers == 2)
            rows[stage, workers] = (seconds, peak, summary)
            print(f"{stage} with {workers} worker(s): {seconds:.1f} s, peak {peak / 2**30:.2f} GiB", flush=True)
    n = views
    print(f"\n== scale: synthetic scene, {n} views 640x480 (mvs at 320 px), Dask LocalCluster ==")
    print(f"{'stage':<10}{'1 worker s':>12}{'2 workers s':>13}{'speed-up':>10}{'peak GiB':>10}")
    for stage in ("features", "matching", "sfm", "mvs"):
        one = rows[stage, 1]
        two = rows.get((stage, 2))
        cells = f"{two[0]:>13.1f}{one[0] / two[0]:>10.2f}" if two else f"{'(in process)':>13}{'':>10}"
        peak = max(one[1], two[1] if two else 0)
        print(f"{stage:<10}{one[0]:>12.1f}{cells}{peak / 2**30:>10.2f}")
    matched = rows["matching", 1][2].get("pairs", 0)
    print(f"pairs matched {matched} of {n * (n - 1) // 2} exhaustive ({100 * matched / (n * (n - 1) / 2):.1f}%)")
    cfg = MatchingConfig()
    for size, pairs in pair_growth(ws, cfg.neighbors, cfg.vocabulary_words):
        print(f"  first {size:>4} views: {pairs:>6} retrieval pairs = {pairs / size:.2f} n = "
              f"{pairs / (size * math.log2(size)):.2f} n log2 n")
    figures = recon.api.evaluate(ws, scene)["poses"]
    print(f"registered {figures['registered']}/{figures['total']}   AUC@1/3/5 {figures['auc@1']:.1f} / "
          f"{figures['auc@3']:.1f} / {figures['auc@5']:.1f}")


SURVEY = {"lines": 12, "width": 480, "height": 360, "gps_sigma": 3.0}
#: SIFT features per photo for both methods: 1024 instead of 8192 cuts matching about tenfold (about an
#: hour for the section on two busy cores); pair selection is what is compared
SURVEY_FEATURES = 1024


def spatial_section(scene: Path, ws: Path, views: int) -> dict:
    """Retrieval against spatial matching on the GPS-tagged survey; prints the table, writes
    ``<ws>/../spatial.json`` and returns its rows."""
    from recon.synth.survey import render_survey

    if not (scene / "gt" / "scene.json").exists():
        start = time.perf_counter()
        render_survey(scene, views=views, lines=SURVEY["lines"], width=SURVEY["width"], height=SURVEY["height"],
                      gps_sigma=SURVEY["gps_sigma"])
        print(f"rendered the {views}-view survey in {time.perf_counter() - start:.0f} s", flush=True)
    rows = {}
    for method in ("retrieval", "spatial"):
        result = recon.run(REPO / "pipelines" / "sparse.yaml", images=str(scene / "images"), workspace=str(ws),
                           until="sfm", force=["matching", "sfm"], matching={"method": method},
                           features={"max_num_features": SURVEY_FEATURES})
        figures = recon.api.evaluate(ws, scene)["poses"]
        summary = result.summaries["matching"]
        rows[method] = {"pairs": summary["pairs"], "verified_pairs": summary["verified_pairs"],
                        "matching_s": result.seconds["matching"], "sfm_s": result.seconds["sfm"],
                        "features_s": result.seconds.get("features", 0.0),
                        **{k: figures[k] for k in ("registered", "total", "auc@1", "auc@3", "auc@5")}}
        print(f"{method}: {summary['pairs']} pairs, matching {result.seconds['matching']:.0f} s, sfm "
              f"{result.seconds['sfm']:.0f} s, {figures['registered']}/{figures['total']} registered", flush=True)
    growth = survey_pair_growth(ws, views)
    n = views
    print(f"\n== scale: spatial matching, synthetic aerial survey of {n} views {SURVEY['width']}x{SURVEY['height']}, "
          f"{SURVEY['lines']} flight lines, GPS noise {SURVEY['gps_sigma']:.0f} m, {SURVEY_FEATURES} SIFT per photo ==")
    print(f"{'method':<11}{'pairs':>7}{'pairs/n':>9}{'verified':>10}{'matching s':>12}{'sfm s':>8}"
          f"{'registered':>12}{'AUC@1':>7}{'AUC@3':>7}{'AUC@5':>7}")
    for method, r in rows.items():
        print(f"{method:<11}{r['pairs']:>7}{r['pairs'] / n:>9.2f}{r['verified_pairs']:>10}{r['matching_s']:>12.1f}"
              f"{r['sfm_s']:>8.1f}{r['registered']:>8}/{r['total']:<3}{r['auc@1']:>7.1f}{r['auc@3']:>7.1f}"
              f"{r['auc@5']:>7.1f}")
    print("pairs chosen among the first n views (per view):")
    for size, retrieval, spatial in growth:
        print(f"  n = {size:>4}: retrieval {retrieval:>6} ({retrieval / size:.2f})   spatial {spatial:>6} "
              f"({spatial / size:.2f})")
    record = {"views": n, "survey": SURVEY, "max_num_features": SURVEY_FEATURES, "methods": rows,
              "pair_growth": growth}
    (ws.parent / "spatial.json").write_text(json.dumps(record, indent=1))
    return record


def survey_pair_growth(ws: Path, views: int, seed: int = 0) -> list[tuple[int, int, int]]:
    """(n, retrieval pairs, spatial pairs) chosen among the first n views, for a few n up to all,
    with the default options."""
    import dataclasses

    from recon.products import Published
    from recon.sparse import pairs as pairing
    from recon.sparse.photos import inspect_photo
    from recon.stages.matching import MatchingConfig, image_similarity

    cfg = MatchingConfig()
    names = sorted(p.name for p in (ws / "images").iterdir())
    tags = [inspect_photo(ws / "images" / name, name).gps for name in names]  # as ingest reads them
    positions = pairing.gps_positions([{"name": n, "gps": dataclasses.asdict(t)} for n, t in zip(names, tags)],
                                      names)
    similarity = image_similarity(Published(ws).database, names, cfg.vocabulary_words, seed)
    out = []
    for n in sorted({views // 6, views // 3, 2 * views // 3, views}):
        sim = similarity[:n, :n]
        spatial = pairing.spatial_matching_pairs(positions[:n], sim, cfg.spatial_neighbors, cfg.spatial_max_distance,
                                                 cfg.neighbors, cfg.spatial_retrieval)
        out.append((n, len(pairing.retrieval_pairs(sim, cfg.neighbors)), len(spatial)))
    return out


if __name__ == "__main__":
    raise SystemExit(main())
