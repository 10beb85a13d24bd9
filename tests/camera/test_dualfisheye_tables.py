"""Remap tables of the dual-fisheye model: interpolated between exactly projected nodes, the two-lens
cut tables of the 8-bit path, the memory-mapped disk cache, and what ``solidkit capture unwarp``
imports (the command as users run it)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from solidkit.camera import dualfisheye as D
from solidkit.camera.lens import load_profile, project
from solidkit.envmap.coords import direction_from_coords, rotation_from_ypr


def _exact(profile, in_size, H, R):
    """Per-lens (x, y, seen) by projecting every output pixel centre."""
    prof = profile.scaled(*in_size)
    yy, xx = np.meshgrid(np.arange(H) + 0.5, np.arange(2 * H) + 0.5, indexing="ij")
    d = direction_from_coords(xx, yy, H) @ R
    out = []
    for lens in prof.lenses:
        x, y, theta = project(lens, d)
        out.append((x, y, theta < math.radians(lens.max_angle_deg)))
    return out


def test_interpolated_tables_within_tolerance_of_exact_projection():
    """Nodes every s px, bilinear between: within MAP_TOLERANCE_PX (1/64 px) of projecting every pixel."""
    prof = load_profile("theta-s")
    R = np.asarray(rotation_from_ypr(0.4, math.radians(2.0), math.radians(-1.0)))
    in_size, H = (1920, 960), 960
    assert D._grid_step(prof.scaled(*in_size), H) > 1  # the interpolated path is the one under test
    got = {i: [] for i in range(2)}
    for _r0, _r1, lenses in D.lens_samples(prof, in_size, H, R):
        for i, (x, y, m) in enumerate(lenses):
            got[i].append((x, y, m))
    for i, (x, y, seen) in enumerate(_exact(prof, in_size, H, R)):
        gx = np.concatenate([g[0] for g in got[i]])
        gy = np.concatenate([g[1] for g in got[i]])
        err = np.hypot(gx - x, gy - y)[seen]
        assert err.max() < D.MAP_TOLERANCE_PX, (i, err.max())


@pytest.mark.parametrize(
    "feather, in_size, H", [(10.0, (1024, 512), 256), (0.0, (1024, 512), 256), (10.0, (1920, 960), 960)]
)
def test_cut_tables_are_the_full_tables_of_the_dominant_lens(feather, in_size, H):
    """Exact projection (256 rows) and the node grid, where the weights come from the interpolated
    margin difference alone (960 rows: every block passes _clip_is_exact)."""
    prof = load_profile("theta-v")
    R = np.asarray(rotation_from_ypr(0.2, 0.1, -0.05))
    grid = D._NodeGrid(prof, in_size, H, R)
    assert (grid.s > 1) == (H == 960)
    if grid.s > 1:
        (_, _, m0), (_, _, m1) = grid.nodes
        assert all(
            D._clip_is_exact(m0[grid.slab(a, b)], m1[grid.slab(a, b)], math.radians(feather)) for a, b in grid.blocks()
        )
    full = D.build_maps(prof, in_size, H, R, feather)
    cut = D.build_cut_maps(prof, in_size, H, R, feather)
    lead, idx, w0 = full.band()
    assert np.array_equal(cut.lead.astype(bool), lead) and np.array_equal(cut.band, idx)
    assert np.allclose(cut.band_w0.reshape(-1)[: idx.size], w0, atol=1e-6)
    cov = full.coverage
    assert cut.coverage == pytest.approx(float(cov.mean()))
    # the dominant lens' table wherever one lens is seen alone; in the band, where both lenses are sampled from the
    # band tables and blended, the node grid's cells across the cut give another position that is never seen
    one = cov.copy()
    one.reshape(-1)[idx] = False
    assert np.array_equal(np.where(lead[..., None], full.map1[0], full.map1[1])[one], cut.map1[one])
    assert np.array_equal(np.where(lead, full.map2[0], full.map2[1])[one], cut.map2[one])
    img = np.random.default_rng(0).integers(0, 256, (in_size[1], in_size[0], 3), dtype=np.uint8)
    for i in range(2):  # the band tables sample what each lens' full table samples there
        whole = cv2.remap(img, full.map1[i], full.map2[i], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        assert np.array_equal(cut.sample_band(img, i).reshape(-1, 3)[: idx.size], whole.reshape(-1, 3)[idx])


def test_cut_tables_cached_on_disk_memory_mapped(tmp_path):
    prof = load_profile("theta-v")
    D.clear_cache()
    built, s1 = D.get_cut_maps(prof, (512, 256), 128, cache_dir=tmp_path)
    D.clear_cache()  # waits for the background write
    files = list(tmp_path.glob("cut*-*.tables"))
    loaded, s2 = D.get_cut_maps(prof, (512, 256), 128, cache_dir=tmp_path)
    assert (s1, s2, len(files)) == ("built", "disk", 1)
    assert isinstance(loaded.map1, np.memmap) and not loaded.map1.flags.writeable
    for k, v in built.arrays().items():
        assert np.array_equal(np.asarray(getattr(loaded, k)), v), k
    files[0].write_bytes(files[0].read_bytes()[:5000])  # truncated by a crash or a full disk: rebuilt
    D.clear_cache()
    _, s3 = D.get_cut_maps(prof, (512, 256), 128, cache_dir=tmp_path)
    assert s3 == "built"
    D.clear_cache()


HEAVY = (
    "torch",
    "kornia",
    "colour",
    "pycolmap",
    "mitsuba",
    "drjit",
    "fastapi",
    "uvicorn",
    "scipy",
    "OpenEXR",
    "PIL",
    "rawpy",
    "pvlib",
)

_RUN = """
import json, sys
from solidkit.cli import main
sys.argv = ["solidkit", *sys.argv[1:]]
main()
print(json.dumps(sorted(sys.modules)))
"""


def test_unwarp_command_imports_no_heavy_library(tmp_path):
    """``solidkit capture unwarp`` (a whole run, 8-bit in and out) loads typer, rich, cv2, numpy, pydantic,
    never torch/kornia/colour/pycolmap/mitsuba/fastapi, nor SciPy/OpenEXR/PIL (importing them made every
    command's start 0.77 s)."""
    from solidkit.capture.unwarp import render_fisheye

    prof = load_profile("theta-v")
    img = render_fisheye(lambda d: 0.2 + 0.6 * (d[..., :1] > 0) * np.ones(3), prof, (512, 256))
    src = tmp_path / "dual.png"
    cv2.imwrite(str(src), (np.clip(img, 0, 1) * 255).astype(np.uint8))
    env_cmd = [
        sys.executable,
        "-c",
        _RUN,
        "capture",
        "unwarp",
        str(src),
        "-o",
        str(tmp_path / "pano.png"),
        "--profile",
        "theta-v",
        "--json",
    ]
    proc = subprocess.run(
        env_cmd,
        capture_output=True,
        text=True,
        timeout=120,
        env={**__import__("os").environ, "SOLIDKIT_CACHE_DIR": str(tmp_path / "cache")},
    )
    assert proc.returncode == 0, proc.stderr
    modules = set(json.loads(proc.stdout.strip().splitlines()[-1]))
    loaded = {m.split(".")[0] for m in modules}
    assert {"typer", "cv2", "numpy"} <= loaded
    # NumPy is its own array-API namespace: array_api_compat's numpy wrapper costs ~0.1 s to import
    assert "array_api_compat.numpy" not in modules
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))
    assert (tmp_path / "pano.png").is_file()


def test_disk_cache_is_bounded_least_recently_used_first(tmp_path):
    """Each levelling has its own tables (~150 MB at Theta V size): the folder is kept under a size bound."""
    prof = load_profile("theta-v")
    D.clear_cache()
    keys = []
    for k, pitch in enumerate((0.0, 1.0, 2.0)):
        R = np.asarray(rotation_from_ypr(0.0, math.radians(pitch), 0.0))
        D.get_cut_maps(prof, (512, 256), 128, R, cache_dir=tmp_path)
        D.clear_cache()
        keys.append({f.name for f in tmp_path.glob("*.tables")} - {n for kk in keys for n in kk})
        if k == 1:  # the first file is read again: it becomes the most recently used
            D.get_cut_maps(prof, (512, 256), 128, np.eye(3), cache_dir=tmp_path)
            D.clear_cache()
    files = sorted(tmp_path.glob("*.tables"))
    one = files[0].stat().st_size
    D._evict(tmp_path, keep=tmp_path / "none", max_bytes=2 * one)
    left = {f.name for f in tmp_path.glob("*.tables")}
    assert left == keys[0] | keys[2], (left, keys)  # the one built second and never read again went
