"""Monte Carlo noise of a virtual campaign's truth probes against samples per pixel, and the render cost.

Usage::

    .venv/bin/python benchmarks/bench_truth_noise.py CAMPAIGN --spp 32,256 [--scene scene01 ...] [--name NAME]

For every truth probe of ``CAMPAIGN`` (``solidkit synth campaign``), its scene is rebuilt
(:mod:`solidkit.synth.truth_rerender`, checked against the truth) and the probe rendered at each
``--spp`` (non-glass; glass scenes x the campaign's ``glass_spp_factor``, as the generator does) with
:func:`solidkit.synth.truth_probes.render_truth_probe`, on a seed the campaign does not use; the
noise is the split-half estimate of the render record (``noise_psnr_db``: even vs odd passes, paper
tonemap; checked against two independent renders in ``tests/synth/test_truth.py``). Nothing in the
campaign is written. Writes ``benchmarks/results/align-truth-noise[-NAME].json``.

Run it niced on one drjit thread (``DRJIT_NUM_THREADS=1 nice -n 10``): seconds per probe are for that.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from solidkit.synth.campaign import sample_config
from solidkit.synth.mitsuba_variant import mitsuba, variant
from solidkit.synth.sample import Generator, derive_seed
from solidkit.synth.truth_probes import render_truth_probe
from solidkit.synth.truth_rerender import _rebuild, _scene_index, read_campaign

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("campaign", type=Path)
    ap.add_argument("--spp", default="32,256", help="comma-separated samples per pixel (non-glass)")
    ap.add_argument("--scene", action="append", default=[], help="only these scenes (repeatable)")
    ap.add_argument("--name", default=None)
    args = ap.parse_args()
    spps = [int(s) for s in args.spp.split(",")]
    _, truth = read_campaign(args.campaign)
    cfg = truth.config
    gen = Generator(truth.seed, sample_config(cfg))
    mi = mitsuba()
    rows = []
    for st in truth.scenes:
        if args.scene and st.id not in args.scene:
            continue
        built = _rebuild(mi, gen, st, truth.seed, cfg)
        factor = cfg.glass_spp_factor if built["glass"] else 1
        for c, ct in enumerate(st.captures):
            if ct.probe is None:
                continue
            glint = None if ct.glint_body is None else np.asarray(ct.R_scene_from_body) @ np.asarray(ct.glint_body)
            for spp in spps:
                t0 = time.perf_counter()
                _, rec = render_truth_probe(
                    built["scene"],
                    np.asarray(ct.position),
                    built["cam"].pano_rotation,
                    cfg.probe_height,
                    spp * factor,
                    seed=derive_seed(truth.seed, _scene_index(st.id), 7000 + c),
                    sun=built["light"].sun,
                    glint=glint,
                    firefly_k=cfg.firefly_k,
                )
                row = {
                    "scene": st.id,
                    "probe": ct.id,
                    "glass": built["glass"],
                    "spp": spp * factor,
                    "noise_psnr_db": rec["noise_psnr_db"],
                    "fireflies_replaced": rec["fireflies_replaced"],
                    "seconds": round(time.perf_counter() - t0, 1),
                }
                rows.append(row)
                print(json.dumps(row), flush=True)
    summary = {}
    for spp in spps:
        for glass in (False, True):
            sel = [r for r in rows if r["spp"] == spp * (cfg.glass_spp_factor if glass else 1) and r["glass"] == glass]
            if sel:
                db = [r["noise_psnr_db"] for r in sel]
                summary[f"{'glass' if glass else 'other'}@{sel[0]['spp']}"] = {
                    "n": len(sel),
                    "noise_median_db": float(np.median(db)),
                    "noise_min_db": float(min(db)),
                    "seconds_median": float(np.median([r["seconds"] for r in sel])),
                }
    out = {
        "campaign": str(args.campaign),
        "seed": truth.seed,
        "probe_height": cfg.probe_height,
        "mitsuba": mi.__version__,
        "variant": variant(),
        "machine": platform.processor() or platform.machine(),
        "summary": summary,
        "rows": rows,
    }
    path = HERE / "results" / f"align-truth-noise{'-' + args.name if args.name else ''}.json"
    path.write_text(json.dumps(out, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
