"""The SOLID-Net-style real test set: build it from a campaign, load, validate, compare, review, export, import.

A test set is a folder with ``testset.json`` (:class:`TestSet`; format: docs/testset.md): per scene
the photo and its 320x240 model input with K, pitch and roll, the sun, and per probe its pixel and
the aligned 256x128 LDR (and HDR) probe.

Quick use::

    from solidkit.testset import build_testset, load_testset, validate_testset
    build_testset("campaign/", "testset/")       # after solidkit ingest and solidkit align
    ts = load_testset("testset/")
    ts.dataset_version, [(s.id, len(s.probes)) for s in ts.scenes]
    assert validate_testset("testset/") == []    # every problem, with its scene and file

The names below are imported lazily (on first access): :class:`TestsetDataset` pulls in torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "BuildReport": "build",
    "build_testset": "build",
    "load_testset": "build",
    "TestSet": "schema",
    "json_schema": "schema",
    "Problem": "validate",
    "validate_testset": "validate",
    "TestsetDiff": "diff",
    "diff_testsets": "diff",
    "show_testset": "show",
    "TestsetDataset": "dataset",
    "SoldNetItem": "sold_net",
    "export_sold_net": "sold_net",
    "read_sold_net": "sold_net",
    "import_sold_net": "sold_net_import",
    "export_croissant": "publish",
    "ExportInfo": "facts",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.testset.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.testset' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
