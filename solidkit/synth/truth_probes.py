"""The virtual campaign's truth probes: HDR panoramas clean enough to hold an aligned probe against.

A truth probe is the scene's radiance seen from a probe position (a ``(H, 2H)`` equirect in the
photo's panorama frame; :mod:`solidkit.synth.campaign`). It is what an aligned probe is scored
against, so its own Monte Carlo noise caps every score: an aligned 256x128 probe is averaged
down from a 1920x960 unwarp of a 512-px rendered panorama (16 samples per pixel, so ~16 x 16 =
256 samples per truth pixel) and is much smoother than a truth rendered directly with 32
samples. Measured on campaign seed 11 (``benchmarks/results/align-truth.md``): the old truths'
noise (32 spp, glass scenes 128; paper tonemap) was 27-35 dB PSNR (median 34), while the capture's
own probe at the true rotation reaches 34-42 dB against this module's truths (noise 39-48 dB).

:func:`render_truth_probe` renders with ``spp`` samples per pixel (box filter, each sample
jittered in its pixel: ``spp`` samples are an ``spp``-fold supersampled box average) in passes of
at most ``pass_samples`` samples (memory: Mitsuba's LLVM backend holds a whole pass as one
wavefront; always an even number, ``spp >= 2``), each pass with its own seed; the difference of the
even and the odd passes' means measures the result's noise (``record['noise_psnr_db']``,
:func:`noise_psnr_db`) at no extra cost.

**Fireflies** (stated, not hidden: the truth is *not* the unbiased path-traced radiance). The
captures are rendered with ``pano_spp`` samples per pixel and then given the campaign's firefly
treatment (:func:`solidkit.synth.sample.suppress_fireflies`, a pixel ``k`` times its 3x3 median
replaced by it: the stand-in for Cycles' "clamp indirect" of the paper's renderer), which removes
rare, bright paths (the sun reflected by windows and glass onto the street: sparkles that converge
very slowly). The truth must be the same scene *as the captures show it*, so each pass of the truth
has at most the captures' samples per pixel (``firefly_spp``) and gets the same treatment before the
passes are averaged: its expectation is that of a capture render, and its noise falls as more
passes are added. Measured on seed 11 (``benchmarks/results/align-truth.md``): treating only the
final mean of 1024 samples left the sparkles in (a glass probe's true-rotation PSNR fell from 28.0
to 23.7 dB); per pass it rose to 33.0 dB. The directly seen sun and the sun's glint on glass
(:func:`solidkit.synth.fieldwork.glint_direction`) are protected from the treatment, being real
sharp peaks.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from solidkit.envmap import tonemap
from solidkit.synth.sample import derive_seed, render_panorama, sun_mask_panorama, suppress_fireflies

__all__ = [
    "PASS_SAMPLES",
    "TRUTH_RENDER_VERSION",
    "clean_truth_probe",
    "needed_spp",
    "noise_psnr_db",
    "pass_plan",
    "psnr",
    "render_truth_probe",
]

PASS_SAMPLES = 1 << 23
"""Most samples (pixels x spp) of one Mitsuba pass (8.4 M: a 512-px campaign panorama at 16 spp)."""

TRUTH_RENDER_VERSION = 4
"""Version of the truth-probe recipe: 1 = one pass of ``probe_spp``, firefly treatment with only the sun
protected (the truth of the campaigns written before 2026-11-29); 2 = passes, glints protected, recorded per probe;
3 = 2 plus the noise target (:func:`clean_truth_probe`); 4 = 3 with the firefly treatment per pass of the captures'
sample density (``firefly_spp``)."""


def pass_plan(height: int, spp: int, pass_samples: int = PASS_SAMPLES) -> list[int]:
    """Samples per pixel of each pass for a ``(height, 2 height)`` panorama: ``spp`` in the fewest passes that
    fit ``pass_samples``, and an even number of them (two halves for the noise estimate) when ``spp >= 2``."""
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    per = max(1, pass_samples // (2 * height * height))
    n = math.ceil(spp / per)
    n = min(spp, n + n % 2)
    return [spp // n + (1 if i < spp % n else 0) for i in range(n)]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two images in ``[0, 1]`` (e.g. in the paper's tonemap): ``10 log10(1 / MSE)``; inf if equal."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def noise_psnr_db(half_a: np.ndarray, half_b: np.ndarray) -> float:
    """Monte Carlo noise of the mean of two independent renders, as a PSNR (dB) in the paper's tonemap.

    ``half_a`` and ``half_b`` (HDR, same shape) are independent estimates of one image with the same
    number of samples; their difference is pure noise with 4 times the variance of their mean, so
    the mean's noise PSNR is ``PSNR(tonemap(a), tonemap(b)) + 10 log10(4)`` (the tonemap linearised
    around the image: exact for small noise).
    """
    return psnr(tonemap(np.asarray(half_a, np.float32)), tonemap(np.asarray(half_b, np.float32))) + 10.0 * math.log10(
        4.0
    )


def render_truth_probe(
    scene: Any,
    position: np.ndarray,
    rotation: np.ndarray,
    height: int,
    spp: int,
    *,
    seed: int,
    sun: np.ndarray | None = None,
    glint: np.ndarray | None = None,
    firefly_k: float = 10.0,
    firefly_spp: int | None = None,
    pass_samples: int = PASS_SAMPLES,
) -> tuple[np.ndarray, dict[str, Any]]:
    """One truth probe (module doc): HDR ``(height, 2 height, 3)`` float32 and its render record.

    Parameters
    ----------
    scene : the Mitsuba scene (geometry and the lighting's emitter).
    position : ``(3,)`` scene-frame position of the probe's lens, metres.
    rotation : ``(3, 3)`` frame of the panorama (the photo's panorama frame, conventions §3).
    height : panorama height in pixels (width ``2 height``).
    spp : samples per pixel in all.
    seed : the first pass's sampler seed (later passes: ``derive_seed(seed, pass)``).
    sun, glint : scene-frame unit directions of the sun and of its glint on glass seen from
        ``position`` (None: none): protected from the firefly treatment.
    firefly_k : the firefly threshold (``<= 0``: no treatment).
    firefly_spp : when given, the render is made of passes of at most this many samples per pixel,
        each given the firefly treatment before they are averaged: the treatment then sees outliers
        of the size it sees in a capture rendered with that many samples (module doc); None: one
        treatment of the final mean.

    Returns
    -------
    image : ``(height, 2 height, 3)`` linear radiance, float32.
    record : ``spp``, ``passes``, ``seed``, ``firefly_k``, ``fireflies_replaced`` (pixels),
        ``noise_psnr_db`` (:func:`noise_psnr_db` of the even and the odd passes, before the firefly
        treatment; None for an odd ``spp``), ``version`` (:data:`TRUTH_RENDER_VERSION`).
    """
    per_pass = pass_samples if not firefly_spp else min(pass_samples, int(firefly_spp) * 2 * height * height)
    plan = pass_plan(height, spp, per_pass)
    keep = sun_mask_panorama(sun, rotation, height)
    if glint is not None:
        g = sun_mask_panorama(glint, rotation, height, 2.0)
        keep = g if keep is None else keep | g
    halves = np.zeros((2, height, 2 * height, 3), np.float64)  # even and odd passes: two independent estimates
    replaced = 0
    for i, n in enumerate(plan):
        s = seed if i == 0 else derive_seed(seed, i)
        one = render_panorama(scene, position, rotation, height, n, seed=s)
        if firefly_spp:
            one, r = suppress_fireflies(one, keep, firefly_k, wrap=True)
            replaced += r
        halves[i % 2] += n * one.astype(np.float64)
    img = (halves.sum(0) / sum(plan)).astype(np.float32)
    noise = None
    if len(plan) >= 2 and sum(plan[0::2]) == sum(plan[1::2]):
        noise = round(noise_psnr_db(halves[0] / sum(plan[0::2]), halves[1] / sum(plan[1::2])), 2)
    if not firefly_spp:
        img, replaced = suppress_fireflies(img, keep, firefly_k, wrap=True)
    record = {
        "version": TRUTH_RENDER_VERSION,
        "spp": int(sum(plan)),
        "passes": len(plan),
        "seed": int(seed),
        "firefly_k": float(firefly_k),
        "firefly_spp": int(firefly_spp) if firefly_spp else None,
        "fireflies_replaced": int(replaced),
        "height": int(height),
        "noise_psnr_db": noise,
    }
    return img, record


def needed_spp(noise_db: float | None, spp: int, target_db: float | None, max_spp: int) -> int | None:
    """Samples per pixel that bring a render of ``spp`` samples with noise ``noise_db`` to ``target_db``.

    Monte Carlo noise power falls as ``1 / spp``: ``spp 10^((target - noise) / 10)``, rounded up to an
    even number and capped at ``max_spp``. None when no more samples are needed (no target, the
    noise already at or above it, or the cap at ``spp``).
    """
    if not target_db or noise_db is None or noise_db >= target_db:
        return None
    n = min(int(max_spp), math.ceil(spp * 10.0 ** ((target_db - noise_db) / 10.0)))
    n += n % 2
    return n if n > spp else None


def clean_truth_probe(
    scene: Any,
    position: np.ndarray,
    rotation: np.ndarray,
    height: int,
    spp: int,
    *,
    seed: int,
    noise_target_db: float | None,
    max_spp: int,
    sun: np.ndarray | None = None,
    glint: np.ndarray | None = None,
    firefly_k: float = 10.0,
    firefly_spp: int | None = None,
    pilot: dict[str, Any] | None = None,
    pass_samples: int = PASS_SAMPLES,
) -> tuple[np.ndarray | None, dict[str, Any]]:
    """A truth probe whose noise reaches ``noise_target_db`` where ``max_spp`` allows (recipe version 3).

    A pilot of ``spp`` samples (:func:`render_truth_probe`, ``seed``) measures the probe's noise; when
    it is under the target a **fresh** render of :func:`needed_spp` samples (seed ``derive_seed(seed,
    1000)``) replaces it: the pilot's samples are not mixed in, so the choice of the sample count,
    made on the pilot alone, leaves the final render's expectation unbiased. Glass caustics
    converge slower than ``1 / spp`` (heavy-tailed paths): their records show the noise reached.

    ``pilot``: the render record of an existing render of this probe at ``spp`` with this seed
    (what the pilot would be, sample for sample): used instead of rendering it again.

    Returns
    -------
    image : ``(height, 2 height, 3)`` float32, or None when ``pilot`` was given and is kept.
    record : the kept render's record (:func:`render_truth_probe`) plus ``version`` 3, ``base_spp``,
        ``noise_target_db``, ``max_spp`` and ``pilot`` (its ``spp`` and ``noise_psnr_db``).
    """
    kw: dict[str, Any] = dict(
        sun=sun, glint=glint, firefly_k=firefly_k, firefly_spp=firefly_spp, pass_samples=pass_samples
    )
    img: np.ndarray | None = None
    if pilot is None:
        img, record = render_truth_probe(scene, position, rotation, height, spp, seed=seed, **kw)
    else:
        record = {k: v for k, v in pilot.items() if k not in ("previous", "check_psnr_db", "rendered_utc")}
    first = {"spp": record["spp"], "noise_psnr_db": record["noise_psnr_db"]}
    n = needed_spp(record["noise_psnr_db"], spp, noise_target_db, max_spp)
    if n is not None:
        img, record = render_truth_probe(scene, position, rotation, height, n, seed=derive_seed(seed, 1000), **kw)
    record.update(
        version=TRUTH_RENDER_VERSION,
        base_spp=int(spp),
        noise_target_db=noise_target_db,
        max_spp=int(max_spp),
        pilot=first,
    )
    return img, record
