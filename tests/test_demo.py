"""The README's main job (`make demo`) runs end to end and its numbers are right."""

import json

from solidkit.demo import run_demo


def test_demo_end_to_end(tmp_path):
    summary = run_demo(tmp_path, log=lambda *_: None)
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    sun = summary["sun"]["core"]
    assert sun["found"]
    assert abs(sun["azimuth_deg"] - 35.93) < 0.3 and abs(sun["elevation_deg"] - 47.77) < 0.3
    assert summary["resize"]["max_rel_error"] < 1e-6
    assert 0 < summary["photo"]["panorama_coverage"] < 0.1
    assert summary["sh"]["D_vs_sh_mean_rel_error"] < 0.1
    assert len(summary["model"]["pixels"]) == 2 and "found" in summary["model"]["sun"]
    for name in ("predicted_sky.exr", "predicted_local_0.exr", "predicted_local_1.png", "report.png", "photo.png", "photo.exr", "panorama_256x128.exr", "diffuse_convolution.exr"):
        assert (tmp_path / name).stat().st_size > 0
