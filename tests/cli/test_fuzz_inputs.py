"""A small run of ``benchmarks/fuzz_inputs.py``: mutated JPEG/DNG/EXR/PNG/HDR/TOML/JSON inputs through every
fuzzed command, no crash, no hang, no internal error, no codec chatter (the benchmark runs 1000 and more)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "fuzz_inputs.py"


@pytest.mark.slow
def test_fuzzed_inputs_are_handled(monkeypatch) -> None:
    spec = importlib.util.spec_from_file_location("fuzz_inputs", BENCH)
    assert spec is not None and spec.loader is not None
    fuzz = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "fuzz_inputs", fuzz)  # its dataclasses look their module up
    spec.loader.exec_module(fuzz)
    res = fuzz.run(count=140, seed=7, timeout=180.0, only=[], keep=None, quiet=True)
    rows = res["per_command"]
    assert set(rows) == set(fuzz.WEIGHTS) and all(row["inputs"] > 0 for row in rows.values())
    assert all(code == 0 for code in res["baseline"].values()), res["baseline"]
    assert res["failures"] == [], res["failures"][:5]
    for command, row in rows.items():
        assert row["crashes"] == row["hangs"] == row["exit_1_internal"] == row["with_chatter"] == 0, (command, row)
