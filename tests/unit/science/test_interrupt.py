"""A cancelled owner's fit stops at its next least-squares solve (service.science.interrupt), in its
own thread only; without an owner's question, nothing changes."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from service.science.fitting.lsq import Block, solve_blocks
from service.science.interrupt import Interrupted, checkpoint, interruptible


def _problem():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(200, 3))
    return [Block.make("w", a)], a @ np.array([1.0, -2.0, 0.5])


def test_a_solve_stops_once_its_owner_asks_and_not_before():
    blocks, target = _problem()
    stop = threading.Event()
    with interruptible(stop.is_set):
        assert np.allclose(solve_blocks(blocks, target).coef, [1.0, -2.0, 0.5])
        stop.set()
        with pytest.raises(Interrupted):
            solve_blocks(blocks, target)
    assert np.allclose(solve_blocks(blocks, target).coef, [1.0, -2.0, 0.5])  # the question is gone


def test_a_fit_code_that_catches_exception_does_not_swallow_the_stop():
    with interruptible(lambda: True), pytest.raises(Interrupted):
        try:
            checkpoint()
        except Exception:  # a fallback in a fit
            pytest.fail("the stop was caught as an ordinary exception")


def test_another_threads_question_does_not_reach_this_thread():
    """Two jobs fit at once: one's cancel, asked while both are inside their fits, stops only its own."""
    blocks, target = _problem()
    inside, release, stopped = threading.Event(), threading.Event(), []

    def cancelled_job():
        with interruptible(lambda: True):
            inside.set()
            release.wait(10)
            try:
                solve_blocks(blocks, target)
            except Interrupted:
                stopped.append(True)

    t = threading.Thread(target=cancelled_job)
    t.start()
    assert inside.wait(10)
    assert np.allclose(solve_blocks(blocks, target).coef, [1.0, -2.0, 0.5])  # this thread asked nothing
    release.set()
    t.join(10)
    assert stopped == [True]
