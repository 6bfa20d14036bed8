"""The dependency rule and the products contract (docs/ARCHITECTURE.md), checked on the source.

cli -> api -> pipeline -> stages -> libraries: a stage module imports no other stage module and not
the API; a library imports none of the workspace, the pipeline, the stages or the API. File names
that stages share are spelled only in recon/products.py.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from recon import products
from recon.stage import REGISTRY, producer

PACKAGE = Path(__file__).resolve().parents[2] / "recon"
#: modules above the libraries: the only ones that may import the workspace, pipeline, stages or API
TOP = {"recon.cli", "recon.api", "recon.pipeline", "recon.stage", "recon.workspace", "recon.executor",
       "recon.bench", "recon.scale_bench", "recon.quality_bench", "recon.__init__", "recon.products"}
FORBIDDEN_IN_LIBRARIES = ("recon.workspace", "recon.pipeline", "recon.stages", "recon.api", "recon.stage")


def modules() -> dict[str, Path]:
    return {".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts): p for p in PACKAGE.rglob("*.py")}


def imports(path: Path) -> set[str]:
    """Every module an import statement in ``path`` names (at any depth: lazy imports count too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return found


def test_stage_modules_import_no_other_stage_and_not_the_api():
    bad = []
    for name, path in modules().items():
        if name.startswith("recon.stages.") and name != "recon.stages.__init__":
            for target in imports(path):
                if (target.startswith("recon.stages.") and not target.startswith(name)) or \
                        target == "recon.api" or target.startswith("recon.api.") or \
                        target in ("recon.pipeline", "recon.cli"):
                    bad.append(f"{name} imports {target}")
    assert not bad, "\n".join(bad)


def test_libraries_import_no_workspace_pipeline_stage_or_api():
    bad = []
    for name, path in modules().items():
        if name in TOP or name.startswith("recon.stages"):
            continue
        for target in imports(path):
            if any(target == f or target.startswith(f + ".") for f in FORBIDDEN_IN_LIBRARIES):
                bad.append(f"{name} imports {target}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("literal", ['"images.json"', '"sparse"'])
def test_shared_file_names_are_spelled_only_in_the_products(literal):
    spelled = [f"{name}:{n}" for name, path in modules().items() if name != "recon.products"
               for n, line in enumerate(path.read_text().splitlines(), 1) if literal in line]
    assert not spelled, "\n".join(spelled)


def test_every_stage_produces_one_product_and_reads_products_made_before_it():
    order = list(REGISTRY)
    for name, stage in REGISTRY.items():
        assert issubclass(stage.produces, products.Product), name
        for product in (*stage.requires, *stage.optional):
            assert order.index(producer(product)) < order.index(name), (name, product)
