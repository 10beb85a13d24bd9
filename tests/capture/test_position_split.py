"""Positions on a camera's own card split by the scene's shooting rhythm, not one fixed gap."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

from solidkit.capture.campaign import ingest
from solidkit.capture.manifest import load_manifest
from tests.capture.test_ingest import T0, write_shot

SUN, PROBE, MID, LONG = (1, 25000), (1, 2500), (1, 640), (1, 160)


def _rhythm_card(root: Path) -> dict[str, list[list[str]]]:
    """A DCIM card with a slow scene and, 20 minutes later, a fast one; the true positions' file names per scene.

    Slow: 3 positions 4 minutes apart, each a bracket at 8 s intervals and, a minute later, the sun frame (a
    fixed 45 s split cuts every sun frame off its bracket). Fast: 4 positions 25 s apart, each the sun frame and
    a bracket at 1 s intervals (a fixed 45 s split merges them all)."""
    d = root / "DCIM" / "100RICOH"
    n = [0]
    truth: dict[str, list[list[str]]] = {"slow": [], "fast": []}

    def shot(dt: float, exposure: tuple[int, int]) -> str:
        n[0] += 1
        name = f"R00100{n[0]:02d}.JPG"
        write_shot(d / name, T0 + timedelta(seconds=dt), exposure)
        return name

    for k in range(3):
        base = 240.0 * k
        truth["slow"].append([shot(base + dt, e) for dt, e in ((0, PROBE), (8, MID), (16, LONG), (76, SUN))])
    for k in range(4):
        base = 1200.0 + 28.0 * k
        truth["fast"].append([shot(base + dt, e) for dt, e in ((0, SUN), (1, PROBE), (2, MID), (3, LONG))])
    return truth


def test_slow_and_fast_rhythms_on_one_card_split_into_their_positions(tmp_path) -> None:
    """Both scenes come out with their true positions, each bracket with its sun frame; a fixed 45 s gap gave the
    slow scene 6 positions and the fast one 1. Given explicitly (``--probe-gap``), another gap is a fixed split."""
    truth = _rhythm_card(tmp_path / "card")
    camp = tmp_path / "camp"
    ingest(tmp_path / "card", camp, products=False)
    m = load_manifest(camp)
    assert len(m.scenes) == 2
    for sc, want in zip(sorted(m.scenes, key=lambda s: s.id), (truth["slow"], truth["fast"])):
        got = [sorted(Path(m.shot(s).sources[0].path).name for s in p.shots) for p in sc.probes]
        assert got == want, sc.id
        assert all(p.sun_frame is not None and len(p.brackets) == 1 for p in sc.probes), sc.id

    ingest(tmp_path / "card", camp, products=False, grouping={"probe_gap_s": 30.0})
    fixed = sorted(load_manifest(camp).scenes, key=lambda s: s.id)
    assert [len(sc.probes) for sc in fixed] == [6, 1]
