"""Typed option fields: the one way every configurable thing in recon declares its options.

A stage's or operation's options are a frozen dataclass whose every field is declared with
:func:`opt`: a default, a one-line doc (shown by ``recon stages`` and ``recon config show``) and
optional bounds. ``recon.config`` validates YAML against these dataclasses.
"""

from __future__ import annotations

import dataclasses
from typing import Any


def opt(default: Any, doc: str, *, ge: float | None = None, le: float | None = None,
        gt: float | None = None, lt: float | None = None, affects_output: bool = True) -> Any:
    """Declare an option field: default value, one-line doc and optional numeric bounds.

    ``affects_output=False`` marks options that change how work is done but not its result
    (chunk sizes, thread counts): they stay out of the cache key, so changing one re-runs nothing.
    """
    meta = {"doc": doc, "ge": ge, "le": le, "gt": gt, "lt": lt, "affects_output": affects_output}
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    if dataclasses.is_dataclass(default) and not isinstance(default, type):
        return dataclasses.field(default_factory=lambda: dataclasses.replace(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def doc_of(field: dataclasses.Field) -> str:
    """The one-line doc of a field declared with :func:`opt`."""
    return field.metadata.get("doc", "")


def output_options(obj: Any) -> dict:
    """The options of a config dataclass that determine its stage's output (the cache-key part)."""
    out = {}
    for field in dataclasses.fields(obj):
        if not field.metadata.get("affects_output", True):
            continue
        value = getattr(obj, field.name)
        out[field.name] = output_options(value) if dataclasses.is_dataclass(value) else value
    return out
