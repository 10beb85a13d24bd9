"""Labels of a campaign: the label store (human and automatic labels, history, undo), review, the browser app.

Quick use::

    from solidkit.labeling import CampaignIndex, LabelStore, agreement, review_all
    store = LabelStore("campaign/")               # campaign/labels/labels.sqlite
    [(label.key, label.value, label.source) for label in store.list("sun")]
    reviews = review_all(CampaignIndex("campaign/"), store)
    [r.key for r in reviews if r.open_disagreement]  # what needs a second look
    agreement(CampaignIndex("campaign/"), store)["heading"]["annotators"]  # median / p95 apart, per annotator

The names below are imported lazily (on first access): the app pulls in FastAPI.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "LabelStore": "store",
    "Label": "store",
    "Change": "store",
    "LabelConflict": "store",
    "store_path": "store",
    "CampaignIndex": "tasks",
    "Review": "review",
    "review_item": "review",
    "review_all": "review",
    "agreement": "review",
    "Verdict": "store",
    "Note": "store",
    "create_app": "app",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"solidkit.labeling.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'solidkit.labeling' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
