"""Scale benchmark: a synthetic scene of 300 views through features, matching, sfm and mvs on a Dask
cluster of one, then two, worker processes (issue 8).

Per stage it prints the wall time with 1 and 2 workers and the peak memory (resident set of this
process and all its children, the workers included, sampled every 0.2 s); for matching, the pairs
matched against the exhaustive count and how the retrieval pair count grows with the number of
images (pairs / n and pairs / (n log2 n) on the first n views); and the reconstruction's registered
views and AUC against the scene's ground truth. sfm runs once (in this process, COLMAP's threads).

    python -m recon.bench --only scale [--out DIR]      (or: python -m recon.scale_bench)
"""

from __future__ import annotations

import argparse
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
    from recon.stages.matching import MatchingConfig
    from recon.synth import render_scene

    parser = argparse.ArgumentParser(prog="python -m recon.scale_bench")
    parser.add_argument("--out", type=Path, default=REPO / "bench_out" / "scale")
    parser.add_argument("--views", type=int, default=VIEWS)
    args = parser.parse_args(argv)
    scene, ws = args.out / "scene", args.out / "ws"
    if not (scene / "gt" / "scene.json").exists():
        start = time.perf_counter()
        render_scene(scene, views=args.views, width=640, height=480, seed=0)
        print(f"rendered {args.views} views in {time.perf_counter() - start:.0f} s", flush=True)
    rows = {}
    for workers in (1, 2):
        for stage in ("features", "matching", "sfm", "mvs"):
            if stage == "sfm" and workers == 2:
                continue
            seconds, peak, summary = run_stage(scene, ws, stage, workers, force=workers == 2)
            rows[stage, workers] = (seconds, peak, summary)
            print(f"{stage} with {workers} worker(s): {seconds:.1f} s, peak {peak / 2**30:.2f} GiB", flush=True)
    n = args.views
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
