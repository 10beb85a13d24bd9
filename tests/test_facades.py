"""The packages' public API: every name a façade lists resolves, is listed by ``dir()``, and is the
one its module makes public; no two façades give one name to two things; importing them stays cheap."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys
import types

import pytest

FACADES = [
    "model",
    "envmap",
    "metrics",
    "align",
    "capture",
    "testset",
    "finetune",
    "labeling",
    "synth",
    "calibration",
    "camera",
]
HEAVY = ("torch", "kornia", "mitsuba", "scipy", "pvlib", "fastapi", "matplotlib", "rawpy", "pycolmap")


def _package(name: str) -> types.ModuleType:
    return importlib.import_module(f"solidkit.{name}")


@pytest.mark.parametrize("name", FACADES)
def test_every_public_name_resolves_and_is_listed(name):
    pkg = _package(name)
    public = list(pkg.__all__)
    assert public and len(set(public)) == len(public)
    submodules = {m.name for m in pkgutil.iter_modules(pkg.__path__)}
    assert not set(public) & submodules, "a name that is also a sub-module is shadowed once the sub-module is imported"
    listed = dir(pkg)
    for n in public:
        obj = getattr(pkg, n)
        assert not isinstance(obj, types.ModuleType), n
        assert n in listed, n
        where = getattr(pkg, "_EXPORTS", {}).get(n)
        if where is not None:  # the name its module makes public, not a private or imported one
            assert n in importlib.import_module(f"solidkit.{name}.{where}").__all__, f"{n} not in {where}.__all__"
    with pytest.raises(AttributeError):
        pkg.no_such_name  # noqa: B018


@pytest.mark.parametrize("name", FACADES)
def test_each_facade_says_what_the_package_does_with_a_quick_use(name):
    doc = _package(name).__doc__ or ""
    if name != "envmap":  # the panorama core lists its sub-modules instead
        assert "Quick use::" in doc
        example = doc.split("Quick use::", 1)[1].strip().split("\n\n", 1)[0].splitlines()
        assert 3 <= len(example) <= 6
        assert f"from solidkit.{name} import" in example[0] or f"from solidkit import {name}" in example[0]


def test_no_name_means_two_things():
    owners: dict[str, tuple[str, object]] = {}
    for name in FACADES:
        pkg = _package(name)
        for n in pkg.__all__:
            obj = getattr(pkg, n)
            if n in owners:
                assert owners[n][1] is obj, (
                    f"{n}: solidkit.{owners[n][0]} and solidkit.{name} give it to different things"
                )
            owners[n] = (name, obj)


def test_importing_the_facades_imports_nothing_heavy():
    code = (
        "import sys; import "
        + ", ".join(f"solidkit.{n}" for n in FACADES)
        + f"; print(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
