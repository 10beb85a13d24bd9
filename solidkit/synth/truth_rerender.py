"""Re-render only the truth probes of an existing virtual campaign (``solidkit synth campaign-truth``).

A campaign's captures cost most of its render time (54 min for a campaign of 6 scenes, seed 11); its truth probes
are a small part. Upgrading the truth of an existing campaign (more samples, the version-2 recipe
of :mod:`solidkit.synth.truth_probes`) must not touch the card.

Per scene the scene is rebuilt exactly as :func:`solidkit.synth.campaign.generate_campaign`
built it, from the campaign's seed and settings and the truth's own record (sector, capture
positions): the block and glass facades, the photo camera and the lighting (the same attempt
sequence). Before anything is written the rebuilt scene is checked against the truth (block
seed, glass panels, photo camera, lighting description and sun direction), and each new probe
against the stored one (PSNR in the paper's tonemap at 1/4 size, where the old truth's noise
is averaged away, at least ``min_check_db``): a solidkit whose generator changed since the
campaign was made would render another scene, and is refused (one-line :class:`InputError`,
nothing changed).

The recipe is :func:`solidkit.synth.truth_probes.clean_truth_probe` (a first render of ``spp``,
glass scenes x ``glass_spp_factor``; a fresh one with more samples where it is noisier than the
noise target), with the campaign's own ``pano_spp`` as the firefly treatment's samples per pass.

Writes, each atomically: ``truth/<scene>/<probe>.exr`` (render record in its header), then that
scene's ``scene.json`` (the probe's :attr:`ProbeTruth.render` record: spp, measured noise, the
previous render's spp, version and noise, the check), and at the end ``truth/truth.json`` (records,
the config's ``probe_spp``/``probe_noise_db``/``probe_max_spp`` and ``renderer['truth_probes']``)
and the same settings in ``truth/campaign.json`` (so that they describe the campaign as it now is).
Idempotent and resumable: a probe whose record has this recipe and these settings is skipped; a
stored first render of this recipe is reused. Nothing under ``card/`` is opened for writing.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from solidkit.envmap import read_exr, tonemap
from solidkit.envmap.resample import resize
from solidkit.errors import InputError
from solidkit.fsutil import atomic_write_text
from solidkit.synth.campaign import (
    SCENE_FILE,
    SETTINGS_FILE,
    probe_exr_meta,
    sample_config,
    scene_block,
    scene_lighting,
    write_truth_exr,
)
from solidkit.synth.campaign_truth import CampaignConfig, SceneTruth, TruthError, load_truth
from solidkit.synth.mitsuba_variant import mitsuba, variant
from solidkit.synth.sample import Generator, derive_seed
from solidkit.synth.scene import to_mitsuba
from solidkit.synth.truth_probes import PASS_SAMPLES, TRUTH_RENDER_VERSION, clean_truth_probe, psnr

__all__ = ["read_campaign", "rerender_truth", "check_psnr_db"]

log = logging.getLogger(__name__)


def check_psnr_db(new: np.ndarray, old: np.ndarray, factor: int = 4) -> float:
    """PSNR (dB) of two HDR probes in the paper's tonemap after an area reduction by ``factor``."""
    h = max(2, new.shape[0] // factor)
    return psnr(tonemap(resize(np.asarray(new, np.float32), h)), tonemap(resize(np.asarray(old, np.float32), h)))


def _scene_index(sid: str) -> int:
    if not (sid.startswith("scene") and sid[5:].isdigit()):
        raise InputError(f"truth scene id {sid!r} is not sceneNN")
    return int(sid[5:]) - 1


def _same(a: Any, b: Any, tol: float = 1e-6) -> bool:
    """JSON-like values equal, numbers within ``tol`` (relative)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k], tol) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y, tol) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return math.isclose(float(a), float(b), rel_tol=tol, abs_tol=tol)
    return a == b


def _rebuild(mi: Any, gen: Generator, st: SceneTruth, seed: int, cfg: CampaignConfig) -> dict[str, Any]:
    """The scene ``st`` as the generator built it; :class:`InputError` where it differs from the truth."""
    s = _scene_index(st.id)
    block, cam, panels, glass = scene_block(gen, s, st.sector, seed, cfg)
    problems = []
    if block.seed != st.block_seed:
        problems.append(f"block seed {block.seed} vs {st.block_seed}")
    if not _same([p.to_json() for p in panels], st.glass_panels):
        problems.append("glass panels")
    cam_now = json.loads(json.dumps(cam.to_json()))
    if not _same(cam_now, st.photo.camera):
        problems.append("photo camera")
    geometry = to_mitsuba(block, None, tex_size=4)
    positions = [np.asarray(c.position, np.float64) for c in st.captures]
    if not problems:
        light = scene_lighting(mi, gen, geometry, cam, positions, panels, glass, s, seed, cfg, st.id)
        if not _same(json.loads(json.dumps(light.meta, default=float)), st.lighting):
            problems.append("lighting")
        sun_ok = (light.sun is None) == (st.sun_scene is None) and (
            light.sun is None or float(np.asarray(light.sun) @ np.asarray(st.sun_scene)) > math.cos(math.radians(1e-3))
        )
        if not sun_ok:
            problems.append("sun direction")
    if problems:
        raise InputError(
            f"{st.id}: this solidkit does not rebuild the scene the campaign was rendered from "
            f"({', '.join(problems)} differ); truth left unchanged"
        )
    return {"scene": to_mitsuba(block, light.emitter()), "cam": cam, "light": light, "glass": glass, "s": s}


def read_campaign(campaign: str | os.PathLike) -> tuple[dict[str, Any], Any]:
    """The settings (``truth/campaign.json``) and :class:`CampaignTruth` of a complete campaign; one-line
    :class:`InputError` for anything else."""
    root = Path(campaign)
    settings_path, truth_path = root / "truth" / SETTINGS_FILE, root / "truth" / "truth.json"
    if not settings_path.is_file() or not truth_path.is_file():
        raise InputError(
            f"{root}: not a complete virtual campaign (needs truth/{SETTINGS_FILE} and truth/truth.json "
            "from 'solidkit synth campaign')"
        )
    try:
        settings = json.loads(settings_path.read_text())
        truth = load_truth(truth_path)
    except (OSError, ValueError, TruthError) as exc:
        raise InputError(f"{root}: unreadable campaign truth ({str(exc).splitlines()[0]})") from None
    if not isinstance(settings, dict) or settings.get("seed") != truth.seed:
        raise InputError(
            f"{settings_path}: seed {settings.get('seed') if isinstance(settings, dict) else None} "
            f"is not truth.json's seed {truth.seed}"
        )
    return settings, truth


def rerender_truth(
    campaign: str | os.PathLike,
    *,
    spp: int | None = None,
    noise_db: float | None = None,
    max_spp: int | None = None,
    scenes: list[str] | None = None,
    min_check_db: float = 25.0,
    pass_samples: int = PASS_SAMPLES,
    progress: Callable[[str, str, str], None] | None = None,
) -> dict[str, Any]:
    """Re-render the truth probes of ``campaign`` (module doc) with the recipe of :func:`clean_truth_probe`.

    Parameters
    ----------
    campaign : a folder of ``solidkit synth campaign`` (``truth/campaign.json`` and ``truth/truth.json``).
    spp, noise_db, max_spp : samples per pixel of a probe's first render (glass scenes: times
        ``config.glass_spp_factor``), its noise target (PSNR dB, paper tonemap; 0: none) and the most
        samples per pixel for it; defaults: :class:`CampaignConfig`'s ``probe_spp``, ``probe_noise_db``
        and ``probe_max_spp``.
    scenes : scene ids to re-render (default: all); the settings change only when all are done.
    min_check_db : least PSNR of a new probe against the stored one at 1/4 size (module doc).
    progress : called ``(scene, probe, "rendered" | "kept" | "skipped")`` per probe.

    Returns
    -------
    dict : ``rendered``, ``kept`` (an existing render at ``spp`` that meets the target: record
        updated), ``skipped`` (up to date) probe counts, ``spp``, ``noise_db``, ``max_spp``,
        ``seconds_per_probe`` (rendered ones), ``complete``, ``probes`` (per probe: scene, probe,
        spp, noise, check against the stored probe).
    """
    import time

    root = Path(campaign)
    truth_dir = root / "truth"
    settings_path, truth_path = truth_dir / SETTINGS_FILE, truth_dir / "truth.json"
    settings, truth = read_campaign(root)
    cfg = truth.config
    defaults = CampaignConfig()
    spp = int(spp if spp is not None else defaults.probe_spp)
    noise_db = float(noise_db if noise_db is not None else defaults.probe_noise_db)
    max_spp = int(max_spp if max_spp is not None else defaults.probe_max_spp)
    if spp < 1 or max_spp < 1 or noise_db < 0:
        raise InputError(f"--spp and --max-spp must be >= 1 and --noise-db >= 0 (got {spp}, {max_spp}, {noise_db:g})")
    wanted = set(scenes) if scenes else None
    known = {st.id for st in truth.scenes}
    if wanted and not wanted <= known:
        raise InputError(f"{root}: no scene {', '.join(sorted(wanted - known))} (scenes: {', '.join(sorted(known))})")
    scfg = sample_config(cfg)
    gen = Generator(truth.seed, scfg)
    target = noise_db or None
    mi = None
    counts = {"rendered": 0, "kept": 0, "skipped": 0}
    seconds = 0.0
    probes: list[dict[str, Any]] = []

    def plan(st: SceneTruth) -> tuple[int, int]:
        glass = cfg.glass_every > 0 and _scene_index(st.id) % cfg.glass_every == min(1, cfg.glass_every - 1)
        base = spp * (cfg.glass_spp_factor if glass else 1)
        return base, max(base, max_spp)

    def up_to_date(rec: dict[str, Any], base: int, cap: int) -> bool:
        return (
            rec.get("version") == TRUTH_RENDER_VERSION
            and rec.get("base_spp") == base
            and rec.get("noise_target_db") == target
            and rec.get("max_spp") == cap
        )

    new_scenes = []
    for st0 in truth.scenes:
        marker = truth_dir / st0.id / SCENE_FILE
        st = SceneTruth.model_validate_json(marker.read_text()) if marker.is_file() else st0  # a resumed run's records
        if wanted is not None and st.id not in wanted:
            new_scenes.append(st)
            continue
        base, cap = plan(st)
        built = None
        for c, ct in enumerate(st.captures):
            if ct.probe is None:
                continue
            rec = ct.probe.render or {}
            exr = root / ct.probe.hdr_file
            if up_to_date(rec, base, cap) and exr.is_file():
                counts["skipped"] += 1
                if progress:
                    progress(st.id, ct.id, "skipped")
                continue
            if built is None:
                mi = mi or mitsuba()
                built = _rebuild(mi, gen, st, truth.seed, cfg)
            t0 = time.perf_counter()
            pseed = derive_seed(truth.seed, built["s"], 200 + c)
            # the stored probe is this recipe's first render when it was made at `base` spp with this seed
            fspp = cfg.pano_spp * base // spp  # the captures' samples per pixel (glass: times the factor)
            pilot = (
                rec
                if (
                    rec.get("version", 1) >= 4
                    and rec.get("spp") == base
                    and rec.get("seed") == pseed
                    and rec.get("firefly_spp") == fspp
                    and rec.get("noise_psnr_db") is not None
                    and exr.is_file()
                )
                else None
            )
            glint = None if ct.glint_body is None else np.asarray(ct.R_scene_from_body) @ np.asarray(ct.glint_body)
            img, record = clean_truth_probe(
                built["scene"],
                np.asarray(ct.position),
                built["cam"].pano_rotation,
                cfg.probe_height,
                base,
                seed=pseed,
                noise_target_db=target,
                max_spp=cap,
                sun=built["light"].sun,
                glint=glint,
                firefly_k=cfg.firefly_k,
                firefly_spp=fspp,
                pilot=pilot,
                pass_samples=pass_samples,
            )
            old, _ = read_exr(exr)
            if img is None:  # the stored render is kept: only its record changes
                what, img, check = "kept", old[..., :3], rec.get("check_psnr_db")
                record.update(previous=rec.get("previous"), check_psnr_db=check, rendered_utc=rec.get("rendered_utc"))
            else:
                what, check = "rendered", round(check_psnr_db(img, old[..., :3]), 2)
                if check < min_check_db:
                    raise InputError(
                        f"{st.id}/{ct.id}: the re-rendered truth probe disagrees with the stored one "
                        f"({check:.1f} dB < {min_check_db:g} dB at 1/4 size): not the scene the captures "
                        "show; truth left unchanged"
                    )
                record.update(
                    previous={
                        "spp": rec.get("spp", cfg.probe_spp * base // spp),
                        "version": rec.get("version", 1),
                        "noise_psnr_db": rec.get("noise_psnr_db"),
                    },
                    check_psnr_db=check,
                    rendered_utc=dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
                )
                seconds += time.perf_counter() - t0
            write_truth_exr(exr, img, probe_exr_meta(st.id, ct.id, record))
            ct.probe.render = record
            atomic_write_text(marker, st.model_dump_json(indent=1))  # after the EXR: a killed run redoes this probe
            counts[what] += 1
            probes.append(
                {
                    "scene": st.id,
                    "probe": ct.id,
                    "what": what,
                    "spp": record["spp"],
                    "noise_psnr_db": record["noise_psnr_db"],
                    "pilot": record["pilot"],
                    "check_psnr_db": check,
                    "fireflies_replaced": record["fireflies_replaced"],
                    "seconds": round(time.perf_counter() - t0, 1),
                }
            )
            log.info(
                "%s/%s: %s, %d spp, noise %.1f dB (first render %.1f dB), %.1f s",
                st.id,
                ct.id,
                what,
                record["spp"],
                record["noise_psnr_db"],
                record["pilot"]["noise_psnr_db"],
                time.perf_counter() - t0,
            )
            if progress:
                progress(st.id, ct.id, what)
        new_scenes.append(st)
    done_all = all(
        up_to_date(ct.probe.render or {}, *plan(st)) for st in new_scenes for ct in st.captures if ct.probe is not None
    )
    wanted_cfg = {"probe_spp": spp, "probe_noise_db": noise_db, "probe_max_spp": max_spp}
    recorded = (
        all(getattr(cfg, k) == v for k, v in wanted_cfg.items())
        and (truth.renderer.get("truth_probes") or {}).get("version") == TRUTH_RENDER_VERSION
    )
    changed = counts["rendered"] + counts["kept"]
    if changed or (done_all and not recorded):
        new_truth = truth.model_copy(update={"scenes": new_scenes})
        if done_all:
            new_truth.config = cfg.model_copy(update=wanted_cfg)
            renderer = dict(truth.renderer)
            renderer["truth_probes"] = {
                "version": TRUTH_RENDER_VERSION,
                **wanted_cfg,
                "glass_spp_factor": cfg.glass_spp_factor,
                "mitsuba": mi.__version__ if mi is not None else truth.renderer.get("mitsuba"),
                "variant": variant() if mi is not None else truth.renderer.get("variant"),
            }
            new_truth.renderer = renderer
        text = new_truth.model_dump_json(indent=1)
        if text != truth_path.read_text():
            atomic_write_text(truth_path, text)
        if done_all and any(settings.get("config", {}).get(k) != v for k, v in wanted_cfg.items()):
            settings["config"].update(wanted_cfg)
            atomic_write_text(settings_path, json.dumps(settings, indent=1))
    return {
        "campaign": str(root),
        "spp": spp,
        "noise_db": noise_db,
        "max_spp": max_spp,
        **counts,
        "complete": done_all,
        "seconds_per_probe": seconds / counts["rendered"] if counts["rendered"] else None,
        "probes": probes,
    }
