"""``MODALFEM_KEEP_AWAKE=1`` (experimental, issue 20): a helper thread yields in a loop while a cloth step runs, only
then, and the step's numbers are the same with it as without it."""

from __future__ import annotations

import time

import numba
import numpy as np
import pytest

from modalfem import _threads
from modalfem._threads import keep_awake, thread_count


def _spins_during(seconds: float) -> int:
    f = _threads._awake.flag
    before = int(f[1])
    time.sleep(seconds)
    return int(f[1]) - before


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs a pool of 2 threads")
def test_the_helper_spins_inside_the_block_only(monkeypatch):
    monkeypatch.setenv("MODALFEM_KEEP_AWAKE", "1")
    with thread_count(2):
        with keep_awake():
            with keep_awake():  # nested blocks: the outer one keeps it running
                pass
            assert _threads._awake.flag[0] == 1
            assert _spins_during(0.05) > 0
        assert _threads._awake.flag[0] == 0
        time.sleep(0.01)  # the helper leaves its loop at its next yield
        assert _spins_during(0.05) == 0
    with thread_count(1):  # one thread: nothing to keep awake
        with keep_awake():
            assert _threads._awake.flag[0] == 0
    monkeypatch.setenv("MODALFEM_KEEP_AWAKE", "0")
    with thread_count(2):
        with keep_awake():
            assert _threads._awake.flag[0] == 0


def test_cloth_steps_give_the_same_numbers_with_the_helper(monkeypatch):
    from modalfem.cloth import scenes

    states = []
    for flag in ("0", "1"):
        monkeypatch.setenv("MODALFEM_KEEP_AWAKE", flag)
        setup = scenes.pile(8)
        for _ in range(15):
            setup.scene.step(setup.dt)
        states.append((setup.scene.x.copy(), setup.scene.v.copy()))
        if flag == "1" and numba.config.NUMBA_NUM_THREADS >= 2 and _threads.threads() >= 2:
            assert _threads._awake is not None and _threads._awake.flag[0] == 0  # stopped after the steps
    assert np.array_equal(states[0][0], states[1][0]) and np.array_equal(states[0][1], states[1][1])
