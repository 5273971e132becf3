"""The gymnasium 1.0 shim (envs/faces/_compat.py): gymnasium's own AutoresetMode where it has one
(1.1+), else a same-named, same-valued Enum that our vector env honours in both modes."""

from __future__ import annotations

import importlib
import importlib.util
import sys

import gymnasium.vector
import numpy as np
import pytest

import overtakezoo.envs.faces._compat as compat
from overtakezoo.envs import make_vec


def test_shim_is_gymnasiums_own_when_present():
    if not hasattr(gymnasium.vector, "AutoresetMode"):
        pytest.skip("gymnasium 1.0.x: no AutoresetMode of its own (the stand-in is tested below)")
    assert compat.HAS_AUTORESET_MODE and compat.AutoresetMode is gymnasium.vector.AutoresetMode


def _fresh_copy(name: str):
    """A new module object executed from ``name``'s file, not put in sys.modules."""
    spec = importlib.util.find_spec(name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def shim_without_gymnasiums_mode(monkeypatch):
    """Fresh copies of the shim and of our vector env as on gymnasium 1.0, where gymnasium.vector has
    no AutoresetMode. The imported modules are left alone (on 1.0 they are that already)."""
    if not hasattr(gymnasium.vector, "AutoresetMode"):
        yield compat, sys.modules["overtakezoo.envs.faces.vector"]
        return
    monkeypatch.delattr(gymnasium.vector, "AutoresetMode")
    shim = _fresh_copy("overtakezoo.envs.faces._compat")
    monkeypatch.setitem(sys.modules, "overtakezoo.envs.faces._compat", shim)  # what the vector copy imports
    vector = _fresh_copy("overtakezoo.envs.faces.vector")
    monkeypatch.undo()
    yield shim, vector


def test_stand_in_has_gymnasium_1_1s_names_and_values(shim_without_gymnasiums_mode):
    shim, _ = shim_without_gymnasiums_mode
    assert not shim.HAS_AUTORESET_MODE
    assert {m.name: m.value for m in shim.AutoresetMode} == {
        "NEXT_STEP": "NextStep",
        "SAME_STEP": "SameStep",
        "DISABLED": "Disabled",
    }
    real = getattr(importlib.import_module("gymnasium.vector.vector_env"), "AutoresetMode", None)
    if real is not None:  # the very names and values of gymnasium's own
        assert [(m.name, m.value) for m in shim.AutoresetMode] == [(m.name, m.value) for m in real]


@pytest.mark.parametrize("given", ["enum", "value", "name"])
def test_vector_env_autoresets_same_step_with_the_stand_in(shim_without_gymnasiums_mode, given):
    shim, vector = shim_without_gymnasiums_mode
    mode = shim.AutoresetMode.SAME_STEP
    arg = {"enum": mode, "value": mode.value, "name": mode.name}[given]
    vec = vector.make_vec(num_envs=3, scenario={"time_limit": 1.0}, autoreset_mode=arg)
    assert vec.metadata["autoreset_mode"] is mode
    vec.reset(seed=0)
    for _ in range(10):
        _, _, term, trunc, infos = vec.step(np.ones(3, np.int64))
    assert trunc.all() and infos["_final_obs"].all()  # replaced in the step that ended them
    np.testing.assert_array_equal(infos["t"], 0.0)
    nxt = vector.make_vec(num_envs=2, autoreset_mode="NextStep")
    assert nxt.metadata["autoreset_mode"] is shim.AutoresetMode.NEXT_STEP
    with pytest.raises(ValueError, match="autoreset_mode"):
        vector.make_vec(num_envs=2, autoreset_mode=shim.AutoresetMode.DISABLED)


def test_default_vector_env_uses_the_shims_mode():
    assert make_vec(num_envs=2).metadata["autoreset_mode"] == compat.AutoresetMode.NEXT_STEP
