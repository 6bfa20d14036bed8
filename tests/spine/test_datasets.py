"""The real photo sets with ground-truth cameras: every photo registers (slow: minutes each)."""

from __future__ import annotations

from pathlib import Path

import pytest

import recon

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
@pytest.mark.datasets
@pytest.mark.parametrize("name,count,min_auc5", [("temple_ring", 47, 75.0), ("fountain_p11", 11, 90.0)])
def test_sparse_pipeline_registers_every_photo(datasets, tmp_path, name, count, min_auc5):
    ws = tmp_path / name
    recon.run(REPO / "pipelines" / "sparse.yaml", images=str(datasets / name / "images"), workspace=str(ws))
    figures = recon.api.evaluate(ws, datasets / name)["poses"]
    assert figures["registered"] == figures["total"] == count
    assert figures["auc@5"] >= min_auc5
