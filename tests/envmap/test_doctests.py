"""The Examples of solidkit.envmap's public functions run as doctests (numpydoc ``Examples`` sections,
as colour-science does), and every public function of envmap has one."""

from __future__ import annotations

import doctest
import importlib
import inspect
import pkgutil

import numpy as np
import pytest

import solidkit.envmap

MODULES = sorted(m.name for m in pkgutil.iter_modules(solidkit.envmap.__path__))  # a new module is covered too


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name):
    module = importlib.import_module(f"solidkit.envmap.{name}")
    with np.printoptions(legacy=False):  # importing colour-science sets numpy's 1.13 legacy printing process-wide
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, report=True)
    assert result.attempted > 0 and result.failed == 0, result


def test_every_public_function_has_an_example():
    missing = []
    for name in MODULES:
        module = importlib.import_module(f"solidkit.envmap.{name}")
        for attr in module.__all__:
            obj = getattr(module, attr)
            if inspect.isfunction(obj) and ">>>" not in (obj.__doc__ or ""):
                missing.append(f"solidkit.envmap.{name}.{attr}")
            if inspect.isfunction(obj) and "Examples\n" not in (obj.__doc__ or ""):
                missing.append(f"solidkit.envmap.{name}.{attr} (no numpydoc 'Examples' heading)")
    assert not missing, missing
