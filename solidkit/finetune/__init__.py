"""Evaluation with the paper's metrics (``solidkit eval``) and sim-to-real fine-tuning (``solidkit finetune``).

Quick use::

    from solidkit.finetune import evaluate_testset
    ev = evaluate_testset("testset/", "model.pt")  # None: the shipped checkpoint; and the baselines
    ev.median("angle_deg/paper"), ev.interval("angle_deg/paper")  # degrees, the model's
    {m: ev.median("local_ssim", m) for m in ev.methods}

Other datasets and methods: :func:`items_from_synth`, :func:`items_from_panoramas`, a
:class:`Method` subclass, then :func:`solidkit.finetune.evaluate.evaluate`; the metrics themselves
are :mod:`solidkit.metrics`. The names below are imported lazily (on first access): they pull in torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Evaluation": "evaluate",
    "evaluate_testset": "evaluate",
    "EvalItem": "evaluate",
    "ItemPrediction": "evaluate",
    "Method": "evaluate",
    "ModelMethod": "evaluate",
    "GlobalAsLocal": "evaluate",
    "MeanBaseline": "evaluate",
    "METRICS": "evaluate",
    "items_from_testset": "evaluate",
    "items_from_synth": "evaluate",
    "items_from_panoramas": "evaluate",
    "default_methods": "evaluate",
    "load_model": "evaluate",
    "evaluate_item": "evaluate",
    "summarise_records": "evaluate",
    "evaluation_report": "report",
    "FineTuneConfig": "finetune",
    "scene_folds": "finetune",
    "run_finetune": "finetune",
    "finetune_report": "finetune",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.finetune.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.finetune' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
