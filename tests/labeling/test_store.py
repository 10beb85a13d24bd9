"""The label store (contract C2): versions, conflicts, auto vs human, history/undo, export, crashes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from solidkit.errors import InputError
from solidkit.labeling.store import LabelConflict, LabelStore, store_path

SUN = {"found": True, "azimuth_deg": 12.5, "elevation_deg": 40.0, "uncertainty_deg": 0.5}


@pytest.fixture
def store(tmp_path):
    return LabelStore(tmp_path)


def test_put_get_versions_and_normalisation(store, tmp_path):
    assert store.get("sun", "s1/p1") is None and store.version("sun", "s1/p1") == 0
    a = store.put("sun", "s1/p1", SUN, source="annotator", annotator="ann", expected_version=0)
    assert (a.version, a.source, a.annotator, a.value["azimuth_deg"]) == (1, "annotator", "ann", 12.5)
    b = store.put(
        "sun", "s1/p1", {**SUN, "azimuth_deg": 180.0}, source="annotator", annotator="ann", expected_version=1
    )
    assert b.version == 2 and b.value["azimuth_deg"] == -180.0  # azimuth in [-180, 180)
    assert store.get("sun", "s1/p1") == b
    h = store.put("heading", "s1/p1", {"yaw_deg": 370.0}, source="auto", annotator="align")
    assert h.value["yaw_deg"] == pytest.approx(10.0)
    n = store.put("sun", "s1/p2", {"found": False, "azimuth_deg": 3.0}, source="annotator", annotator="ann")
    assert n.value["found"] is False and n.value["azimuth_deg"] is None
    assert [(lab.kind, lab.key) for lab in store.list()] == [("heading", "s1/p1"), ("sun", "s1/p1"), ("sun", "s1/p2")]
    assert len(store.list("sun")) == 2
    assert store_path(tmp_path).is_file()
    with store._connect() as con:
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_second_writer_gets_conflict_and_loses_nothing(store):
    store.put("probe_pixel", "s1/p3", {"x": 10, "y": 20}, source="auto", annotator="align")
    seen = store.get("probe_pixel", "s1/p3").version  # both annotators open version 1
    store.put("probe_pixel", "s1/p3", {"x": 100, "y": 200}, source="annotator", annotator="ann", expected_version=seen)
    n_before = len(store.history("probe_pixel", "s1/p3"))
    mine = {"x": 105.5, "y": 198.0}
    with pytest.raises(LabelConflict) as exc:
        store.put("probe_pixel", "s1/p3", mine, source="annotator", annotator="bob", expected_version=seen)
    assert exc.value.current.annotator == "ann" and exc.value.current_version == 2 and "reload" in str(exc.value)
    assert len(store.history("probe_pixel", "s1/p3")) == n_before  # nothing written
    assert store.get("probe_pixel", "s1/p3").value == {"x": 100.0, "y": 200.0}
    again = store.put("probe_pixel", "s1/p3", mine, source="annotator", annotator="bob", expected_version=2)
    assert again.version == 3 and again.value == mine
    assert set(store.opinions("probe_pixel", "s1/p3")) == {"ann", "bob"}


def test_racing_threads_only_one_wins(store):
    results: list[str] = []

    def edit(name: str) -> None:
        try:
            store.put("sun", "s2/p1", SUN, source="annotator", annotator=name, expected_version=0)
            results.append("ok")
        except LabelConflict:
            results.append("conflict")

    threads = [threading.Thread(target=edit, args=(f"a{i}",)) for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results) == ["conflict"] * 5 + ["ok"]
    assert store.version("sun", "s2/p1") == 1 and store.check() == []


def test_auto_never_replaces_a_human_label(store):
    store.put("sun", "s1/p1", SUN, source="auto", annotator="align")
    auto2 = store.put("sun", "s1/p1", {**SUN, "azimuth_deg": 13.0}, source="auto", annotator="align")
    assert auto2.version == 2  # auto over auto is an update
    human = store.put("sun", "s1/p1", {**SUN, "azimuth_deg": 20.0}, source="reviewed", annotator="rev")
    back = store.put("sun", "s1/p1", {**SUN, "azimuth_deg": -5.0}, source="auto", annotator="align")
    assert back == human and store.get("sun", "s1/p1") == human
    last = store.history("sun", "s1/p1")[-1]
    assert (last.op, last.applied, last.value["azimuth_deg"]) == ("kept", False, -5.0)


def test_identical_put_is_idempotent(store):
    a = store.put("sun", "s1/p1", SUN, source="auto", annotator="align", flags=["ambiguous"])
    b = store.put("sun", "s1/p1", dict(SUN), source="auto", annotator="align", flags=["ambiguous"])
    assert a == b and len(store.history("sun", "s1/p1")) == 1


def test_undo_walks_back_and_is_recorded(store):
    store.put("sun", "s1/p1", SUN, source="auto", annotator="align")
    store.put("sun", "s1/p1", {**SUN, "azimuth_deg": 1.0}, source="annotator", annotator="ann")
    store.put("sun", "s1/p1", {**SUN, "azimuth_deg": 2.0}, source="annotator", annotator="ann")
    u1 = store.undo("sun", "s1/p1", "ann")
    assert (u1.value["azimuth_deg"], u1.version, u1.source) == (1.0, 4, "annotator")
    u2 = store.undo("sun", "s1/p1", "ann", expected_version=4)
    assert (u2.value["azimuth_deg"], u2.source, u2.annotator) == (12.5, "auto", "align")
    with pytest.raises(LabelConflict):
        store.undo("sun", "s1/p1", "ann", expected_version=4)
    assert store.undo("sun", "s1/p1", "ann") is None and store.get("sun", "s1/p1") is None
    assert store.version("sun", "s1/p1") == 6
    with pytest.raises(InputError, match="nothing to undo"):
        store.undo("sun", "s1/p1", "ann")
    assert [c.op for c in store.history("sun", "s1/p1")] == ["put", "put", "put", "undo", "undo", "undo"]
    again = store.put("sun", "s1/p1", SUN, source="annotator", annotator="ann", expected_version=6)
    assert again.version == 7 and store.check() == []


@pytest.mark.parametrize(
    "kind, key, value, match",
    [
        ("sunn", "s/p", SUN, "kind"),
        ("sun", "s1", SUN, "key"),
        ("sun", "../x/p", SUN, "key"),
        ("sun_scene", "s1/p1", SUN, "key"),
        ("sun", "s/p", {"found": True, "azimuth_deg": 3.0}, "elevation_deg"),
        ("sun", "s/p", {**SUN, "elevation_deg": 91.0}, "elevation_deg"),
        ("sun", "s/p", {**SUN, "uncertainty_deg": float("nan")}, "NaN|uncertainty"),
        ("probe_pixel", "s/p", {"x": 1.0}, "y"),
        ("probe_pixel", "s/p", {"x": float("inf"), "y": 1.0}, "NaN|infinite|x"),
        ("heading", "s/p", {"yaw_deg": "east"}, "yaw_deg"),
        ("sun", "s/p", {**SUN, "candidates": [{"n": "x" * 70000}]}, "larger"),
    ],
)
def test_bad_labels_are_refused(store, kind, key, value, match):
    with pytest.raises(InputError, match=match):
        store.put(kind, key, value, source="annotator", annotator="ann")
    assert store.list() == []


def test_bad_source_and_annotator(store):
    with pytest.raises(InputError, match="source"):
        store.put("sun", "s/p", SUN, source="human", annotator="ann")
    with pytest.raises(InputError, match="annotator"):
        store.put("sun", "s/p", SUN, source="annotator", annotator="")
    with pytest.raises(InputError, match="annotator"):
        store.put("sun", "s/p", SUN, source="annotator", annotator="a\nb")


def test_export_is_json_and_counts(store, tmp_path):
    store.put("sun", "s1/p1", SUN, source="auto", annotator="align")
    store.put("sun", "s1/p2", SUN, source="annotator", annotator="ann")
    store.put("sun", "s1/p2", {**SUN, "azimuth_deg": 1.0}, source="reviewed", annotator="rev")
    store.put("sun_scene", "s1", SUN, source="auto", annotator="align")
    doc = json.loads(json.dumps(store.export()))
    assert doc["format"] == "solidkit.labels" and doc["campaign"] == tmp_path.name
    assert doc["counts"] == {"sun": {"auto": 1, "reviewed": 1}, "sun_scene": {"auto": 1}}
    by_key = {(d["kind"], d["key"]): d for d in doc["labels"]}
    assert by_key[("sun", "s1/p2")]["annotators"] == ["ann", "rev"] and by_key[("sun", "s1/p2")]["version"] == 2
    ro = LabelStore(tmp_path, readonly=True)
    assert ro.export()["labels"] == doc["labels"]
    with pytest.raises(InputError, match="read-only"):
        ro.put("sun", "s1/p9", SUN, source="auto", annotator="align")


def test_readonly_without_store_and_missing_campaign(tmp_path):
    with pytest.raises(InputError, match="no label store"):
        LabelStore(tmp_path, readonly=True)
    with pytest.raises(InputError, match="not a campaign"):
        LabelStore(tmp_path / "nope")


def test_not_a_database(tmp_path):
    store_path(tmp_path).parent.mkdir()
    store_path(tmp_path).write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(InputError, match="labels.sqlite"):
        LabelStore(tmp_path)


_CHILD = textwrap.dedent(
    """
    import sys, time
    import solidkit.labeling.store as st
    store = st.LabelStore(sys.argv[1])
    if sys.argv[2] == "mid":
        def hook():
            print("MID", flush=True)
            time.sleep(60)
        st._mid_write_hook = hook
        store.put("sun", "s1/p1", {"found": False}, source="annotator", annotator="child")
    else:
        print("LOOP", flush=True)
        i = 0
        while True:
            i += 1
            store.put("probe_pixel", f"s1/p{i % 5}", {"x": i, "y": i}, source="annotator", annotator="child")
    """
)


def _child(campaign, mode):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(campaign), mode], stdout=subprocess.PIPE, text=True, env=env
    )


def test_survives_kill_9_mid_transaction(store, tmp_path):
    before = store.put("sun", "s1/p1", SUN, source="annotator", annotator="ann")
    child = _child(tmp_path, "mid")
    assert child.stdout.readline().strip() == "MID"  # event row inserted, label row not yet, no commit
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    store = LabelStore(tmp_path)
    assert store.check() == []
    assert store.get("sun", "s1/p1") == before
    assert len(store.history("sun", "s1/p1")) == 1  # the half-written change left no trace
    assert (
        store.put("sun", "s1/p1", {"found": False}, source="annotator", annotator="ann", expected_version=1).version
        == 2
    )


def test_survives_kill_9_during_a_stream_of_writes(store, tmp_path):
    child = _child(tmp_path, "loop")
    assert child.stdout.readline().strip() == "LOOP"
    time.sleep(0.8)
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    store = LabelStore(tmp_path)
    assert store.check() == []
    labels = store.list("probe_pixel")
    assert labels, "the child wrote nothing before it was killed"
    for lab in labels:
        applied = [c for c in store.history(lab.kind, lab.key) if c.applied]
        assert lab.version == len(applied) and lab.value == applied[-1].value
