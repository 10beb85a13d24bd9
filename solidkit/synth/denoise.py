"""Denoising of path-traced renders with Intel Open Image Denoise (OIDN), guided by albedo and normals.

Optional: needs the ``pyoidn`` package (``pip install solidkit[denoise]``; the OIDN libraries and
trained weights ship in its wheel, nothing is downloaded at run time).

:func:`render_guides` renders the guides with Mitsuba's ``aov`` integrator through the same camera rays as the
photo's path tracing (same sensor, samples per pixel and seed): ``albedo`` (diffuse reflectance of the first
hit, linear RGB in [0, 1]) and ``normal`` (shading normal of the first hit, world frame); both are 0 where a ray
sees the sky. The colour is the plain render itself, so a denoised render differs from the plain one only by
the filter. :func:`denoise_hdr` runs OIDN's ``RT`` filter in HDR mode (``cleanAux`` off: the guides are
averages of ``spp`` jittered rays, so OIDN prefilters them). Pixels of ``protect`` (the directly seen sun,
radiance far above what OIDN's HDR transfer covers) keep their rendered value.
"""

from __future__ import annotations

import importlib.util
from typing import Any

import numpy as np

from solidkit.errors import InputError
from solidkit.synth.mitsuba_variant import mitsuba
from solidkit.synth.render import integrator

__all__ = ["available", "require", "render_guides", "denoise_hdr", "GUIDE_AOVS"]

GUIDE_AOVS = "albedo:albedo,nn:sh_normal"
"""Mitsuba ``aov`` integrator channels of the guides (3 albedo, then 3 normal channels)."""


def available() -> bool:
    """Whether ``pyoidn`` can be imported."""
    return importlib.util.find_spec("pyoidn") is not None


def require() -> None:
    """Raise :class:`InputError` with the install line when ``pyoidn`` is missing."""
    if not available():
        raise InputError("--denoise needs Intel Open Image Denoise: pip install 'solidkit[denoise]' (pyoidn)")


def render_guides(scene: Any, sensor: Any, spp: int, *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The denoiser's guides of a render: ``(albedo, normal)``, each ``(H, W, 3)`` float32, averaged over ``spp``
    jittered camera rays (``normal`` in the world frame, 0 on sky pixels).

    With the ``sensor``, ``spp`` and ``seed`` of a :func:`~solidkit.synth.render.render_rgb` call, the camera rays
    are that render's own (the ``aov`` integrator draws them from the sampler as the ``path`` integrator does),
    at a small part of its cost (primary hits only).
    """
    mi = mitsuba()
    img = mi.render(
        scene, sensor=sensor, integrator=integrator("aov", aovs=GUIDE_AOVS), spp=int(spp), seed=int(seed) & 0x7FFFFFFF
    )
    raw = np.array(img, dtype=np.float32)
    return raw[..., -6:-3], raw[..., -3:]


def denoise_hdr(
    color: np.ndarray,
    albedo: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    *,
    protect: np.ndarray | None = None,
) -> np.ndarray:
    """OIDN ``RT`` filter (HDR, high quality) of linear radiance ``color`` ``(H, W, 3)`` >= 0; float32 result.

    ``albedo`` in [0, 1] and ``normal`` in [-1, 1] (``(H, W, 3)``) guide it; a normal guide is used
    only together with an albedo guide (OIDN's rule). ``protect`` (bool ``(H, W)``) keeps those pixels as
    rendered.
    """
    require()
    import pyoidn

    c = np.ascontiguousarray(np.clip(np.nan_to_num(np.asarray(color, np.float32)[..., :3]), 0.0, None))
    a = None if albedo is None else np.ascontiguousarray(np.clip(np.asarray(albedo, np.float32), 0.0, 1.0))
    n = None
    if normal is not None and a is not None:
        n = np.ascontiguousarray(np.clip(np.asarray(normal, np.float32), -1.0, 1.0))
    out = np.asarray(pyoidn.denoise(c, a, n, hdr=True, quality="high"), np.float32)
    out = np.clip(out, 0.0, None)
    if protect is not None:
        out[protect] = c[protect]
    return out
