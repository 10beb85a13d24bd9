"""Mitsuba 3 variant selection: ``cuda_ad_rgb`` on a GPU, ``llvm_ad_rgb`` on CPU, ``scalar_rgb`` last.

Measured on this project's machines: drjit's LLVM backend crashes with the system's LLVM 14/15
and works with Debian's ``libllvm19`` (``make system-deps`` installs it). When a
``libLLVM-19.so`` is found, ``DRJIT_LIBLLVM_PATH`` is set to it before drjit is imported;
without it the LLVM variant is skipped. ``SOLIDKIT_MITSUBA_VARIANT`` forces a variant
(e.g. ``scalar_rgb`` to test the fallback). The chosen variant is logged once. ``DRJIT_NUM_THREADS``
(a positive integer) sets drjit's worker threads (``drjit.set_thread_count``; drjit does not read it itself).

Everything in :mod:`solidkit.synth` gets the module through :func:`mitsuba`, which also
registers the solidkit plugins (:mod:`solidkit.synth.plugins`) for the active variant.
"""

from __future__ import annotations

import glob
import logging
import os
from pathlib import Path
from types import ModuleType
from typing import cast

from solidkit.errors import SolidkitError
from solidkit.synth.plugins import register

__all__ = ["VARIANTS", "find_libllvm", "select_variant", "mitsuba", "variant", "is_vectorized"]

log = logging.getLogger("solidkit.synth")

VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
ENV_VARIANT = "SOLIDKIT_MITSUBA_VARIANT"
ENV_THREADS = "DRJIT_NUM_THREADS"
_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM-19.so*",
    "/usr/lib/llvm-19/lib/libLLVM*.so*",
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19*",
)
_state: dict[str, object] = {}


class RendererError(SolidkitError):
    """Mitsuba is missing or no usable variant could be set."""


def find_libllvm() -> Path | None:
    """Path of an LLVM 19 shared library usable by drjit, or None.

    An existing ``DRJIT_LIBLLVM_PATH`` wins when it names a file.
    """
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and Path(env).is_file():
        return Path(env)
    for pattern in _LLVM_GLOBS:
        for hit in sorted(glob.glob(pattern)):
            if Path(hit).is_file():
                return Path(hit)
    return None


def _cuda_present() -> bool:
    return any(Path(p).exists() for p in ("/dev/nvidia0", "/dev/nvidiactl")) or bool(
        os.environ.get("CUDA_VISIBLE_DEVICES")
    )


def select_variant(prefer: str | None = None) -> str:
    """Pick and set the Mitsuba variant; returns its name.

    Order: ``prefer`` or ``$SOLIDKIT_MITSUBA_VARIANT`` if given, else ``cuda_ad_rgb`` (GPU
    present), ``llvm_ad_rgb`` (libLLVM 19 found), ``scalar_rgb``.
    """
    llvm = find_libllvm()
    if llvm is not None:
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", str(llvm))
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - dependency is declared
        raise RendererError(f"mitsuba is not installed ({exc}); pip install 'mitsuba>=3.5'") from None
    forced = prefer or os.environ.get(ENV_VARIANT)
    if forced:
        candidates = [forced]
    else:
        candidates = []
        if _cuda_present():
            candidates.append("cuda_ad_rgb")
        if llvm is not None:
            candidates.append("llvm_ad_rgb")
        candidates.append("scalar_rgb")
    errors = []
    for name in candidates:
        if name not in mi.variants():
            errors.append(f"{name}: not built")
            continue
        try:
            if name.startswith("cuda") and not dr.has_backend(dr.JitBackend.CUDA):
                raise RuntimeError("no CUDA backend")
            if name.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
                raise RuntimeError("no LLVM backend")
            mi.set_variant(name)
        except Exception as exc:  # drjit raises RuntimeError/ImportError for missing backends
            errors.append(f"{name}: {exc}")
            continue
        threads = os.environ.get(ENV_THREADS, "").strip()
        if threads.isdigit() and int(threads) > 0 and dr.thread_count() != int(threads):
            dr.set_thread_count(int(threads))  # drjit itself does not read this variable
        if _state.get("variant") != name:
            log.info(
                "mitsuba %s: variant %s%s", mi.__version__, name, f" (LLVM {llvm})" if name.startswith("llvm") else ""
            )
        _state["variant"] = name
        return name
    raise RendererError("no usable Mitsuba variant: " + "; ".join(errors))


def mitsuba() -> ModuleType:
    """The ``mitsuba`` module with a variant set and solidkit's plugins registered."""
    name = cast("str | None", _state.get("variant")) or select_variant()
    import mitsuba as mi

    if mi.variant() != name:
        mi.set_variant(name)
    registered = cast(set[str], _state.setdefault("registered", set()))
    if name not in registered:
        register(mi)
        registered.add(name)
    return mi


def variant() -> str:
    """The active variant name (selecting one on first use)."""
    mitsuba()
    return str(_state["variant"])


def is_vectorized() -> bool:
    """True for the JIT (llvm/cuda) variants, False for scalar ones."""
    return not variant().startswith("scalar")
