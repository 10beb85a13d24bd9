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
from solidkit.labeling.store import HUMAN_SOURCES, Change, Label, LabelStore, Note, Verdict, opinions
from solidkit.labeling.tasks import CampaignIndex, Item

__all__ = [
    "THRESHOLDS",
    "UNITS",
    "distance",
    "disagreement_flag",
    "Review",
    "review_item",
    "review_all",
    "own_values",
    "user_status",
    "agreement",
]

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


def own_values(history: list[Change]) -> dict[str, Change]:
    """Each annotator's latest value of one label over its whole history (reviews included),
    ``source = "annotator"`` only: what each of them said. ``{annotator: Change}``."""
    return {who: ch for who, ch in opinions(history, since_review=False).items() if ch.source == "annotator"}


def user_status(
    item: Item,
    label: Label | None,
    history: list[Change],
    user: str,
    verdicts: list[Verdict],
    note: Note | None,
) -> dict[str, Any]:
    """An item as one annotator's queue shows it: ``{"status", "comment", "note"}``.

    ``status``: ``returned`` (a reviewer rejected this annotator's current value: ``comment``
    says why), ``done`` (their value, a skip, or a reviewed label settled it), ``flagged``
    (align/ flagged it) or ``left``. Another annotator's label never makes it done.
    """
    mine = own_values(history).get(user)
    settled = label is not None and label.source == "reviewed"
    if mine is not None:
        rejects = [v for v in verdicts if v.annotator == user and v.event == mine.id and v.verdict == "reject"]
        if rejects and not (settled and cast(Label, label).time > rejects[-1].time):
            return {"status": "returned", "comment": rejects[-1].comment, "reviewer": rejects[-1].reviewer}
        return {"status": "done"}
    if note is not None and note.skip:
        return {"status": "done", "skipped": note.text}
    if settled:
        return {"status": "done"}
    return {"status": "flagged" if item.flags else "left"}


def _stats(values: list[float]) -> dict[str, Any]:
    finite = [v for v in values if math.isfinite(v)]
    out: dict[str, Any] = {"n": len(values), "mismatch": len(values) - len(finite)}
    if finite:
        out["median"] = round(float(np.median(finite)), 4)
        out["p95"] = round(float(np.percentile(finite, 95)), 4)
    else:
        out["median"] = out["p95"] = None
    return out


def agreement(index: CampaignIndex, store: LabelStore, kinds: tuple[str, ...] | None = None) -> dict[str, Any]:
    """Agreement summary per task and per annotator.

    For each task: every annotator's latest value of every item (:func:`own_values`) against
    the other annotators' values of the same item (``vs_others``: one distance per pair, in
    :data:`UNITS`) and against the reviewed label where a reviewer settled it (``vs_reviewed``).
    Each set of distances is summarised as ``{n, median, p95, mismatch}`` (``mismatch``:
    "found" against "no sun visible", left out of median and p95). Per annotator also the
    counts of items labelled, rejected and skipped.
    """
    kinds = kinds or tuple(index.items)
    verdicts = store.verdicts()
    notes = store.notes()
    out: dict[str, Any] = {}
    for kind in kinds:
        labels = {lab.key: lab for lab in store.list(kind)}
        histories = store.histories(kind)
        pairs: list[float] = []
        vs_rev: list[float] = []
        per: dict[str, dict[str, list[float]]] = {}
        counts: dict[str, dict[str, int]] = {}
        for key in index.items.get(kind, {}):
            vals = own_values(histories.get(key, []))
            lab = labels.get(key)
            reviewed = lab.value if lab is not None and lab.source == "reviewed" else None
            names = sorted(vals)
            for a in names:
                mine = per.setdefault(a, {"vs_others": [], "vs_reviewed": []})
                counts.setdefault(a, {"labelled": 0, "rejected": 0, "skipped": 0})["labelled"] += 1
                for b in names:
                    d = distance(kind, vals[a].value, vals[b].value) if b != a else None
                    if d is not None:
                        mine["vs_others"].append(d)
                        if b > a:
                            pairs.append(d)
                d = distance(kind, vals[a].value, reviewed)
                if d is not None:
                    mine["vs_reviewed"].append(d)
                    vs_rev.append(d)
        for v in verdicts:
            if v.kind == kind and v.verdict == "reject":
                counts.setdefault(v.annotator, {"labelled": 0, "rejected": 0, "skipped": 0})["rejected"] += 1
        for (k, _key, who), note in notes.items():
            if k == kind and note.skip:
                counts.setdefault(who, {"labelled": 0, "rejected": 0, "skipped": 0})["skipped"] += 1
        out[kind] = {
            "unit": UNITS[kind],
            "threshold": THRESHOLDS[kind],
            "task": {"vs_others": _stats(pairs), "vs_reviewed": _stats(vs_rev)},
            "annotators": {
                who: counts[who]
                | {name: _stats(d) for name, d in per.get(who, {"vs_others": [], "vs_reviewed": []}).items()}
                for who in sorted(counts)
            },
        }
    return out
