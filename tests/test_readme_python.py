"""README "Use it from Python": its script runs as written on a built test set (the analytic campaign
of tests/support/testset_campaign.py) with a tiny checkpoint, and gives the numbers ``solidkit eval`` reports."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from tests.support.testset_campaign import make_campaign

README = Path(__file__).resolve().parents[1] / "README.md"
SECTION = "## Use it from Python"


def readme_script() -> str:
    """The first ``python`` code block of the README's section."""
    text = README.read_text(encoding="utf-8")
    assert SECTION in text, f"README.md has no {SECTION!r} section"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, f"no python code block under {SECTION!r}"
    return blocks[0]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """``my_testset`` and ``my_model.pt``, the paths the README's script names."""
    import torch

    from solidkit.model import SolidNet, preset
    from solidkit.testset import build_testset

    root = tmp_path_factory.mktemp("readme")
    make_campaign(root / "campaign")
    build_testset(root / "campaign", root / "my_testset")
    torch.manual_seed(0)
    SolidNet(preset("tiny")).save(root / "my_model.pt", {"what": "untrained tiny model (test)"})
    return root


@pytest.fixture(scope="module")
def ran(workdir):
    """The README's script run in ``workdir``: its globals and what it printed."""
    import contextlib
    import io
    import os

    import torch

    threads, cwd = torch.get_num_threads(), os.getcwd()
    torch.set_num_threads(1)
    out = io.StringIO()
    scope: dict = {"__name__": "__readme__"}
    try:
        os.chdir(workdir)
        with contextlib.redirect_stdout(out):
            exec(compile(readme_script(), str(README), "exec"), scope)
    finally:
        os.chdir(cwd)
        torch.set_num_threads(threads)
    return scope, out.getvalue()


def test_the_readme_script_runs_and_prints_the_models_numbers(ran):
    scope, printed = ran
    lines = printed.splitlines()
    ev = scope["ev"]
    assert lines[0].endswith(f"{len(scope['testset'].scenes)} scenes") and lines[0].startswith("sha256:")
    assert ev.methods[0] == "solidnet" and len(lines) == 1 + 4 + len(ev.methods)
    ssim = ev.median("local_ssim")
    low, high = ev.interval("local_ssim")
    assert 0 < ssim <= 1 and low <= ssim <= high
    assert lines[1 + 2] == f"local_ssim {ssim} {(low, high)}"
    assert ev.summary["solidnet"]["local_ssim"]["n"] == sum(len(s.probes) for s in scope["testset"].scenes)
    assert ev.median("local_ssim", "mean-sky") is None  # a baseline without local probes


def test_evaluate_testset_gives_what_solidkit_eval_reports(ran, workdir, cli):
    ev = ran[0]["ev"]
    code, stdout, err = cli(
        "eval",
        "--testset",
        workdir / "my_testset",
        "--model",
        workdir / "my_model.pt",
        "-o",
        workdir / "report",
        "--json",
        "--grids",
        "0",
    )
    assert code == 0, err
    reported = json.loads(stdout)["real"]  # and any checkpoint shipped beside the default one, as "ablation: ..."
    assert json.loads(json.dumps(ev.summary, default=float)) == {m: reported[m] for m in ev.methods}
    for name in ("solidnet", "mean-probe"):
        assert ev.median("local_mae", name) == reported[name]["local_mae"]["median"]
    rate = ev.no_sun_rate()
    assert rate is None or math.isclose(rate, reported["solidnet"]["no_sun_rate/core"]["rate"])
    with pytest.raises(KeyError, match="unknown metric"):
        ev.median("ssim")
    with pytest.raises(KeyError, match="no method"):
        ev.median("local_ssim", "nope")
