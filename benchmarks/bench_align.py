"""``solidkit align`` on a rendered virtual campaign, against its truth, plus injected faults.

Usage::

    .venv/bin/python benchmarks/bench_align.py SYNTH_CAMPAIGN_DIR WORK_DIR [--faults] [--name NAME]

``SYNTH_CAMPAIGN_DIR`` holds ``card/`` and ``truth/`` (``solidkit synth campaign``). The card is
ingested into ``WORK_DIR/clean`` (once), aligned (timed; the truth is not read), and measured
with :func:`solidkit.align.evaluate.evaluate`. Peers in the same run: the same probes aligned
with the **true** yaw (upper bound) and with the **compass** yaw (what a team gets without
align), all in the paper's tonemap against the truth probe.

``--faults``: copies of the clean campaign get one fault each (``tests/support/align_faults.py``: sun
painted out at one position, clocks +3 h, photo GPS 30° off, a compass heading +90°, a
textureless probe) and are aligned again; each must be flagged (and the yaws stay right).

Writes ``benchmarks/results/align[-NAME].json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import tests.support.align_faults as align_faults  # noqa: E402
from solidkit.align.evaluate import evaluate, summary  # noqa: E402
from solidkit.align.pipeline import align_campaign  # noqa: E402
from solidkit.align.schema import load_alignment  # noqa: E402
from solidkit.capture.campaign import ingest  # noqa: E402


def _copy(src: Path, dst: Path) -> Path:
    if dst.exists():
        for p in dst.rglob("*"):
            if p.is_file():
                p.chmod(0o644)
        shutil.rmtree(dst)
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("labels", "report*"))
    for p in dst.rglob("*"):
        if p.is_file():
            p.chmod(0o644)
    return dst


def run_faults(clean: Path, work: Path, truth: Path) -> list[dict]:
    al = load_alignment(clean)
    res = evaluate(clean, truth, peers=False)
    rows = res["captures"]
    out = []
    # pick a scene with the sun at 2+ positions and a probe that saw it
    sun_scenes = [sa for sa in al.scenes if sum(c.found for c in sa.sun.captures) >= 2]
    sa = sun_scenes[0] if sun_scenes else al.scenes[0]
    seen = [c.probe for c in sa.sun.captures if c.found and c.probe != sa.camera_probe]
    probe = seen[0] if seen else next(p.id for p in sa.probes if p.role == "probe")
    true_yaw = {(r["scene"], r["probe"]): r["yaw_true"] for r in rows}

    def check(name: str, inject, expect) -> None:
        d = _copy(clean, work / f"fault-{name}")
        what = inject(d)
        t0 = time.perf_counter()
        a = align_campaign(d)
        s = a.scene(sa.id)
        ok, detail = expect(s)
        out.append(
            {
                "fault": name,
                "injected": what,
                "flagged": ok,
                "detail": detail,
                "seconds": round(time.perf_counter() - t0, 1),
            }
        )
        print(f"fault {name}: {'FLAGGED' if ok else 'MISSED'} ({detail})", flush=True)

    def yaw_err(s, pid):
        p = s.probe(pid)
        return None if p.yaw_deg is None else abs((p.yaw_deg - true_yaw[(sa.id, pid)] + 180) % 360 - 180)

    check(
        "sun_occluded",
        lambda d: align_faults.occlude_sun(d, sa.id, probe),
        lambda s: (
            not next(c for c in s.sun.captures if c.probe == probe).found and s.sun.found,
            f"{probe}: found={next(c for c in s.sun.captures if c.probe == probe).found}; "
            f"reason: {next(c for c in s.sun.captures if c.probe == probe).reason}; scene sun found={s.sun.found}",
        ),
    )
    check(
        "clock_plus_3h",
        lambda d: align_faults.shift_clock(d, sa.id, 3.0),
        lambda s: (any(f.startswith("ephemeris") for f in s.sun.flags), "; ".join(s.sun.flags) or "no flag"),
    )
    check(
        "gps_lat_plus_30",
        lambda d: align_faults.move_gps(d, sa.id, 30.0),
        lambda s: (any(f.startswith("ephemeris") for f in s.sun.flags), "; ".join(s.sun.flags) or "no flag"),
    )
    check(
        "heading_plus_90",
        lambda d: align_faults.rotate_heading(d, sa.id, probe, 90.0),
        lambda s: (
            any(f.startswith("compass_disagrees") for f in s.probe(probe).flags) and (yaw_err(s, probe) or 99) < 2.0,
            f"flags {s.probe(probe).flags}; yaw error {yaw_err(s, probe)}",
        ),
    )
    check(
        "textureless",
        lambda d: align_faults.remove_texture(d, sa.id, probe),
        lambda s: (
            any(f.startswith("features_failed") for f in s.probe(probe).flags)
            and "sun" in s.probe(probe).cues
            and s.probe(probe).cues["sun"].ok
            and (yaw_err(s, probe) or 99) < 2.0,
            f"flags {s.probe(probe).flags}; yaw error {yaw_err(s, probe)}",
        ),
    )
    return out


def _fmt(v, nd: int = 2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("synth", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("--faults", action="store_true")
    ap.add_argument("--name", default="")
    args = ap.parse_args()
    truth = args.synth / "truth" / "truth.json"
    clean = args.work / "clean"
    if not (clean / "manifest.json").is_file():
        t0 = time.perf_counter()
        ingest(args.synth / "card", clean)
        print(f"ingest: {time.perf_counter() - t0:.1f} s", flush=True)
    for sub in ("align",):
        if (clean / sub).exists():
            shutil.rmtree(clean / sub)
    t0 = time.perf_counter()
    align_campaign(clean, log=lambda m: print(m, flush=True))
    t_align = time.perf_counter() - t0
    res = evaluate(clean, truth)
    summ = summary(res)
    summ["align_seconds"] = round(t_align, 1)
    print(json.dumps(summ, indent=1))
    out = {"summary": summ, "captures": res["captures"], "scenes": res["scenes"]}
    if args.faults:
        out["faults"] = run_faults(clean, args.work, truth)
    name = "align" + (f"-{args.name}" if args.name else "")
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"{name}.json").write_text(json.dumps(out, indent=1, default=str))
    lines = [
        f"# {name}\n\n",
        f"Campaign {args.synth} (seed {summ['seed']}, {summ['scenes']} scenes, {summ['captures']} captures); "
        f"align {summ['align_seconds']} s (first run, features not cached). Cue columns: the cue's error against "
        "the truth (deg); compass errors are in compass_probe_*.\n\n",
        "| figure | value |\n|---|---|\n",
    ]
    lines += [f"| {k} | {v if not isinstance(v, float) else round(v, 3)} |\n" for k, v in summ.items()]
    lines.append(
        "\n| scene/probe | yaw error (deg) | cue errors (deg) | LDR PSNR (dB) | truth noise floor (dB) | "
        "pixel geometry (deg) | flags |\n|---|---|---|---|---|---|---|\n"
    )
    for r in res["captures"]:
        if r["role"] != "probe":
            continue
        cues = ", ".join(f"{k} {v:+.2f}" for k, v in r["cues"].items() if v is not None and k != "compass")
        flags = ", ".join(sorted({f.split(":")[0] for f in r["flags"]}))
        lines.append(
            f"| {r['scene']}/{r['probe']} | {_fmt(r.get('yaw_error_deg'))} | {cues or '-'} | "
            f"{_fmt(r.get('psnr_db'), 1)} | {_fmt(r.get('truth_noise_floor_db'), 1)} | "
            f"{_fmt(r.get('pixel_geometry_error_deg'), 1)} | {flags} |\n"
        )
    lines.append("\n| scene | sun (truth) | sun found | sun error (deg) | flags |\n|---|---|---|---|---|\n")
    for sc in res["scenes"]:
        flags = "; ".join(f.replace("|", "/") for f in sc["flags"]) or "-"
        lines.append(
            f"| {sc['scene']} | {sc['sun_truth']} | {sc['sun_found']} | {_fmt(sc.get('sun_error_deg'))} | {flags} |\n"
        )
    lines.append(
        "\n| scene/capture | sun visible (truth) | glint seen (truth) | sun error (deg) | glint chosen "
        "| yaw error (deg) | flags at the capture |\n|---|---|---|---|---|---|---|\n"
    )
    for r in res["captures"]:
        glint = "glint_candidate" in r
        lines.append(
            f"| {r['scene']}/{r['probe']} | {r['sun_visible']} | {glint} | {_fmt(r.get('sun_error_deg'))} | "
            f"{r.get('glint_accepted', '-')} | {_fmt(r.get('yaw_error_deg'))} | "
            f"{', '.join(sorted({f.split(':')[0] for f in r['flags']})) or '-'} |\n"
        )
    if args.faults:
        lines.append("\n| fault | injected | flagged | detail |\n|---|---|---|---|\n")
        lines += [
            f"| {f['fault']} | {f['injected']} | {f['flagged']} | {f['detail'].replace('|', '/')} |\n"
            for f in out["faults"]
        ]
    (HERE / "results" / f"{name}.md").write_text("".join(lines))


if __name__ == "__main__":
    main()
