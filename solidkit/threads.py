"""One thread policy for the package: how many threads torch, OpenCV and the BLAS libraries may use.

Two facts set the policy (measured on a shared 2-core machine):

- **Products must not depend on the thread count.** The BLAS libraries that NumPy, SciPy and OpenCV
  bundle (OpenBLAS) split reductions (a least-squares solve, a long dot product) between their
  threads, so the rounding of a result, and hence the bytes of an HDR product, changed with
  ``OMP_NUM_THREADS`` (OpenCV's ``CalibrateDebevec`` solve is one such reduction). Every product and
  every alignment is therefore computed inside :func:`deterministic`, which runs the BLAS libraries
  on one thread; parallelism comes from worker processes (``ingest --jobs``), not from inside them.
- **Oversubscription is slow.** torch's default (one thread per core) ran ``predict`` about 5x slower
  than one thread when another job kept the second core busy. The default (:func:`default_threads`)
  is half the cores (at least one, at most :data:`MAX_DEFAULT_THREADS`): 1 on a 2-core laptop, 8 on
  a 16-core workstation.

The ``solidkit`` command calls :func:`apply_threads` once (``solidkit --threads N``, else the
environment variable :data:`THREADS_ENV`, else the default); the library's entry points (the demo,
evaluation, fine-tuning, ``SolidNet.predict``) call :func:`ensure_threads`, which keeps a count the
process has already set.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from solidkit.errors import InputError

__all__ = [
    "THREADS_ENV",
    "MAX_DEFAULT_THREADS",
    "default_threads",
    "resolve_threads",
    "apply_threads",
    "ensure_threads",
    "deterministic",
    "helper_threads",
    "set_helper_threads",
]

THREADS_ENV = "SOLIDKIT_THREADS"
"""Environment variable with the thread count (a positive integer) when ``--threads`` is not given."""

MAX_DEFAULT_THREADS = 8
"""The default never asks for more threads than this (the networks are small; beyond it nothing is gained)."""


def default_threads(cpu_count: int | None = None) -> int:
    """Half the usable cores, at least 1 and at most :data:`MAX_DEFAULT_THREADS`.

    >>> default_threads(2), default_threads(16), default_threads(64)
    (1, 8, 8)
    """
    n = (
        cpu_count
        if cpu_count is not None
        else len(os.sched_getaffinity(0))
        if hasattr(os, "sched_getaffinity")
        else (os.cpu_count() or 1)
    )
    return max(1, min(MAX_DEFAULT_THREADS, n // 2))


def resolve_threads(threads: int | None = None) -> int:
    """The thread count to use: ``threads`` if given, else :data:`THREADS_ENV`, else :func:`default_threads`.

    Raises :class:`~solidkit.errors.InputError` for a count that is not a positive integer.
    """
    if threads is None:
        raw = os.environ.get(THREADS_ENV, "").strip()
        if not raw:
            return default_threads()
        try:
            threads = int(raw)
        except ValueError:
            raise InputError(f"{THREADS_ENV}={raw!r}: not a whole number of threads") from None
    if threads < 1:
        raise InputError(f"threads must be at least 1, got {threads}")
    return int(threads)


_BLAS_LIMIT: Any = None
_APPLIED: int | None = None
_HELPERS: int | None = None


def helper_threads() -> int:
    """Threads for solidkit's own splits of one computation (a bracket's channel solves, its merge's row
    blocks): one per usable core, or the count :func:`set_helper_threads` set. Their results do not
    depend on it (each piece is computed alone); a worker process of a pool is set to 1, since the pool
    already keeps the cores busy (the splits then only cost: 10-25 % more CPU-s at Theta V size)."""
    if _HELPERS is not None:
        return _HELPERS
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def set_helper_threads(n: int | None) -> None:
    """Set :func:`helper_threads` (``None``: one per core again)."""
    global _HELPERS
    _HELPERS = None if n is None else max(1, int(n))


def apply_threads(threads: int | None = None) -> int:
    """Set torch's intra-op threads (if torch is loaded), OpenCV's and the BLAS libraries' to the
    resolved count (:func:`resolve_threads`); returns it. Later calls replace the earlier setting."""
    global _BLAS_LIMIT, _APPLIED
    import cv2
    from threadpoolctl import threadpool_limits

    n = resolve_threads(threads)
    cv2.setNumThreads(n)
    _BLAS_LIMIT = threadpool_limits(limits=n, user_api="blas")
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)
    else:  # read by torch when it loads
        os.environ["OMP_NUM_THREADS"] = str(n)
    _APPLIED = n
    return n


def ensure_threads() -> int:
    """The policy for library entry points (:func:`solidkit.demo.run_demo`, evaluation, fine-tuning,
    ``SolidNet.predict``): :func:`apply_threads` with the default unless this process has set a count."""
    return _APPLIED if _APPLIED is not None else apply_threads()


def _load_scipy_blas() -> None:
    """Load SciPy's BLAS library now, without importing SciPy where its wheel's own copy can be found.

    A library loaded inside a :func:`deterministic` block is not limited by it. Importing ``scipy.linalg``
    loads it too, but costs 0.3-0.6 CPU-s (its Python layer), a third of ``capture merge``'s fixed cost;
    the wheel's ``scipy.libs/libscipy_openblas*.so`` loaded by path is the same library SciPy links
    later (the loader reuses an object already loaded under its name).
    """
    if "scipy.linalg" in sys.modules or _SCIPY_BLAS:
        return
    import ctypes
    import importlib.util

    spec = importlib.util.find_spec("scipy")
    if spec is None or not spec.origin:
        return  # no SciPy: nothing to load
    libs = sorted((Path(spec.origin).parent.parent / "scipy.libs").glob("libscipy_openblas*.so*"))
    if len(libs) == 1:
        try:
            _SCIPY_BLAS.append(ctypes.CDLL(str(libs[0])))
            return
        except OSError:
            pass
    import scipy.linalg  # noqa: F401  (another build: SciPy's BLAS loaded by importing it)


_SCIPY_BLAS: list[Any] = []


@contextlib.contextmanager
def deterministic() -> Iterator[None]:
    """Within this block the BLAS libraries (NumPy's, SciPy's, OpenCV's OpenBLAS) run on one thread,
    so their reductions, and what is computed from them, do not depend on the thread count."""
    _load_scipy_blas()  # a library loaded inside the block would not be limited
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
