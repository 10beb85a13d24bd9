"""The thread policy (solidkit.threads)."""

from __future__ import annotations

import cv2
import pytest
from threadpoolctl import threadpool_info

from solidkit import threads
from solidkit.errors import InputError


def test_default_is_half_the_cores_within_bounds():
    assert [threads.default_threads(n) for n in (1, 2, 3, 4, 16, 64)] == [1, 1, 1, 2, 8, 8]


def test_an_explicit_count_wins_over_the_environment(monkeypatch):
    monkeypatch.setenv(threads.THREADS_ENV, "3")
    assert threads.resolve_threads() == 3
    assert threads.resolve_threads(2) == 2
    monkeypatch.setenv(threads.THREADS_ENV, "")
    assert threads.resolve_threads() == threads.default_threads()


@pytest.mark.parametrize("value", ["two", "0", "-1", "1.5"])
def test_a_bad_count_is_a_clear_error(monkeypatch, value):
    monkeypatch.setenv(threads.THREADS_ENV, value)
    with pytest.raises(InputError, match="thread"):
        threads.resolve_threads()


def test_apply_sets_torch_opencv_and_blas_and_deterministic_runs_blas_on_one_thread():
    import torch

    before = torch.get_num_threads(), cv2.getNumThreads()
    try:
        assert threads.apply_threads(2) == 2
        assert torch.get_num_threads() == 2 and cv2.getNumThreads() == 2
        assert {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"} == {2}
        with threads.deterministic():
            assert {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"} == {1}
        assert threads.ensure_threads() == 2  # a count the process set is kept
    finally:
        threads.apply_threads(before[0])
        cv2.setNumThreads(before[1])


def test_scipy_loaded_inside_the_block_is_limited_without_importing_it_first():
    """``deterministic`` loads SciPy's BLAS library by path (importing scipy.linalg cost a third of
    ``capture merge``'s fixed time); SciPy imported inside the block then runs on one thread too."""
    import subprocess
    import sys

    code = (
        "import sys, cv2\n"
        "from threadpoolctl import threadpool_info\n"
        "from solidkit import threads\n"
        "threads.apply_threads(2)\n"
        "with threads.deterministic():\n"
        "    print('scipy.linalg' in sys.modules)\n"
        "    import scipy.linalg\n"
        "    print(sorted({lib['num_threads'] for lib in threadpool_info() if lib['user_api'] == 'blas'}))\n"
        "    print(sum('scipy.libs' in lib['filepath'] for lib in threadpool_info()))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "[1]", "1"]


def test_helper_threads_one_per_core_but_one_in_an_ingest_worker():
    """A computation's own splits (channel solves, row blocks) use a thread per core, except in a worker of
    ingest's pool, whose workers already keep the cores busy."""
    from solidkit.capture.campaign import _pool

    cores = threads.helper_threads()
    try:
        threads.set_helper_threads(3)
        assert threads.helper_threads() == 3
    finally:
        threads.set_helper_threads(None)
    assert threads.helper_threads() == cores >= 1
    pool = _pool(2)
    try:
        assert pool.submit(threads.helper_threads).result(timeout=120) == 1
    finally:
        pool.shutdown()
