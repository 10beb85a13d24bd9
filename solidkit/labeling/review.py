"""Review: how far two labels are apart, which items need a second look, and the queue status.

Distances are in the label's own unit: degrees of arc between two sun directions
(``envmap.coords.angular_distance``), pixels between two probe pixels, degrees of wrapped yaw
between two headings. "Found" against "no sun visible" is a disagreement of unbounded size
(``inf``).

An item's status:

- ``done``: a human label (annotator or reviewed) and no open disagreement;
- ``flagged``: not done, and align/ flagged it, or annotators disagree by more than
  :data:`THRESHOLDS` (unless a reviewer settled it after their labels);
- ``left``: everything else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from solidkit.envmap.coords import angular_distance, direction_from_angles, wrap_angle
from solidkit.flags import Flag, FlagCode, has_code
from solidkit.labeling.store import HUMAN_SOURCES, Change, Label, LabelStore, opinions
from solidkit.labeling.tasks import CampaignIndex, Item

__all__ = ["THRESHOLDS", "UNITS", "distance", "disagreement_flag", "Review", "review_item", "review_all"]

#: disagreement worth a reviewer's look (label units)
THRESHOLDS = {"sun": 1.0, "sun_scene": 1.0, "probe_pixel": 12.0, "heading": 2.0}
UNITS = {"sun": "deg", "sun_scene": "deg", "probe_pixel": "px", "heading": "deg"}


def distance(kind: str, a: dict[str, Any] | None, b: dict[str, Any] | None) -> float | None:
    """Distance between two label values of ``kind`` in :data:`UNITS`; None if either is missing."""
    if not a or not b:
        return None
    if kind in ("sun", "sun_scene"):
        if bool(a.get("found")) != bool(b.get("found")):
            return math.inf
        if not a.get("found"):
            return 0.0
        da, db = (
            np.asarray(direction_from_angles(math.radians(v["azimuth_deg"]), math.radians(v["elevation_deg"])))
            for v in (a, b)
        )
        return math.degrees(float(angular_distance(da, db)))
    if kind == "probe_pixel":
        return math.hypot(a["x"] - b["x"], a["y"] - b["y"])
    if kind == "heading":
        return abs(wrap_angle(a["yaw_deg"] - b["yaw_deg"], 360.0))
    raise KeyError(kind)


def disagreement_flag(kind: str, annotator: str, value: dict[str, Any], history: list[Change]) -> str | None:
    """The flag a new human ``value`` by ``annotator`` gets when it lies more than
    :data:`THRESHOLDS` from another annotator's current opinion (since the last review), e.g.
    ``"annotators_disagree: 23.6 px (ann)"``; None when they agree. The flag travels with the
    label into the test set until a reviewer settles it."""
    worst, who = 0.0, None
    for other, ch in opinions(history).items():
        d = distance(kind, value, ch.value) if other != annotator else None
        if d is not None and d > THRESHOLDS[kind] and d >= worst:
            worst, who = d, other
    if who is None:
        return None
    size = "found vs no sun" if math.isinf(worst) else f"{worst:.1f} {'deg' if UNITS[kind] == 'deg' else 'px'}"
    return str(Flag(FlagCode.ANNOTATORS_DISAGREE, f"{size} ({who})"))[:64]


@dataclass
class Review:
    """Review state of one item (JSON-able through :meth:`as_dict`)."""

    kind: str
    key: str
    status: str
    flags: list[str]
    label: Label | None
    opinions: dict[str, dict[str, Any]] = field(default_factory=dict)
    disagreement: float | None = None
    vs_auto: float | None = None
    open_disagreement: bool = False

    def as_dict(self) -> dict[str, Any]:
        def num(x: float | None) -> float | str | None:
            return None if x is None else ("inf" if math.isinf(x) else round(x, 3))

        return {
            "kind": self.kind, "key": self.key, "status": self.status, "flags": self.flags,
            "label": self.label.model_dump(mode="json") if self.label else None,
            "opinions": self.opinions, "disagreement": num(self.disagreement), "vs_auto": num(self.vs_auto),
            "unit": UNITS[self.kind], "open_disagreement": self.open_disagreement,
        }  # fmt: skip


def review_item(item: Item, label: Label | None, history: list[Change]) -> Review:
    """Status, flags and disagreements of one item (``history``: its store history)."""
    ops = opinions(history)
    values = {who: ch.value for who, ch in ops.items() if ch.value is not None}
    pair = [distance(item.kind, a, b) for i, a in enumerate(values.values()) for b in list(values.values())[i + 1 :]]
    dists = [p for p in pair if p is not None]
    dis = max(dists) if dists else None
    human = label is not None and label.source in HUMAN_SOURCES
    auto = (
        item.proposal
        if item.proposal and (item.kind != "heading" or item.proposal.get("yaw_deg") is not None)
        else None
    )
    if auto is None:
        auto = next((c.value for c in reversed(history) if c.source == "auto" and c.value), None)
    vs_auto = distance(item.kind, cast(Label, label).value, auto) if human and auto else None
    # store flags are the codes of align's flags (or whole flags): keep align's flag only
    extra = [f for f in (label.flags if label else []) if not any(f in (a, Flag.parse(a).code) for a in item.flags)]
    flags = list(dict.fromkeys([*item.flags, *extra]))
    open_dis = dis is not None and dis > THRESHOLDS[item.kind]
    if open_dis and not has_code(flags, FlagCode.ANNOTATORS_DISAGREE):
        flags.append(FlagCode.ANNOTATORS_DISAGREE.value)
    if vs_auto is not None and vs_auto > THRESHOLDS[item.kind]:
        flags.append(FlagCode.DIFFERS_FROM_AUTO.value)
    if human and not open_dis:
        status = "done"
    elif open_dis or item.flags:
        status = "flagged"
    else:
        status = "left"
    return Review(
        item.kind, item.key, status, flags, label,
        {who: {"value": ch.value, "source": ch.source, "time": ch.time.isoformat()} for who, ch in ops.items()},
        dis, vs_auto, open_dis,
    )  # fmt: skip


def review_all(index: CampaignIndex, store: LabelStore, kinds: tuple[str, ...] | None = None) -> list[Review]:
    """Reviews of every item of ``kinds`` (all tasks by default), in queue order."""
    kinds = kinds or tuple(index.items)
    out = []
    for kind in kinds:
        labels = {lab.key: lab for lab in store.list(kind)}
        histories = store.histories(kind)
        for key, item in index.items[kind].items():
            out.append(review_item(item, labels.get(key), histories.get(key, [])))
    return out
