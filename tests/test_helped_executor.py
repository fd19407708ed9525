"""A stage beside the bake, helped by the bake's thread while it waits (core/executor.py HelpedExecutor)."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from pdic.core.executor import Beside, Cancelled, HelpedExecutor, Progress, map_chunks


def _helper(executor: HelpedExecutor, stop: threading.Event, ran: list):
    def run():
        while not stop.is_set():
            if executor.help():
                ran.append(threading.get_ident())
    return threading.Thread(target=run, daemon=True)


def test_a_helped_map_keeps_the_order_and_the_values_whoever_runs_each_item():
    executor = HelpedExecutor()
    taken = threading.Event()
    threads = {}

    def work(i):
        threads[i] = threading.get_ident()
        if i == 0:
            assert taken.wait(10)  # the map's own thread holds item 0 until the helper has one
        else:
            taken.set()
        return np.random.default_rng([7, i]).random(3)  # its own stream: the same on any thread

    stop, ran = threading.Event(), []
    helper = _helper(executor, stop, ran)
    helper.start()
    out = executor.map(work, range(40))
    stop.set()
    helper.join()
    assert ran and len(set(threads.values())) == 2  # both threads ran items
    expected = [np.random.default_rng([7, i]).random(3) for i in range(40)]
    assert all(np.array_equal(a, b) for a, b in zip(out, expected))
    assert executor.help() is False  # nothing under way once the map returned


def test_an_item_failing_on_the_helper_is_raised_by_the_map():
    executor = HelpedExecutor()
    started = threading.Event()

    def work(i):
        if i == 0:
            started.set()
            assert helped.wait(10)
            return 0
        raise ValueError(f"item {i}")

    helped = threading.Event()

    def help_once():
        assert started.wait(10)
        executor.help()  # takes item 1, which fails: the helper goes on
        helped.set()

    helper = threading.Thread(target=help_once, daemon=True)
    helper.start()
    with pytest.raises(ValueError, match="item 1"):
        executor.map(work, range(5))
    helper.join()


def test_a_map_inside_an_item_runs_on_its_callers_thread():
    executor = HelpedExecutor()
    inner = executor.map(lambda i: executor.map(lambda j: (i, j, threading.get_ident()), range(3)), range(2))
    me = threading.get_ident()
    assert inner == [[(i, j, me) for j in range(3)] for i in range(2)]


def test_the_waiting_thread_takes_chunks_of_the_side_stage():
    executor = HelpedExecutor()
    waiting = threading.get_ident()
    taken = threading.Event()
    threads = []

    def stage():
        def chunk(index, s):
            threads.append(threading.get_ident())
            if index == 0:
                assert taken.wait(10)  # the side holds its first chunk until the waiting thread took one
            elif threading.get_ident() == waiting:
                taken.set()
            return np.arange(s.start, s.stop).sum()
        out.extend(map_chunks(executor, chunk, [slice(k, k + 1000) for k in range(0, 200_000, 1000)]))

    out: list = []
    side = Beside(stage, Progress(), Progress())
    side.start()
    side.wait(help=executor.help)
    assert out == [np.arange(k, k + 1000).sum() for k in range(0, 200_000, 1000)]
    assert waiting in threads and len(set(threads)) == 2


def test_a_cancel_while_the_waiting_thread_helps_stops_the_stage_and_raises_cancelled():
    executor = HelpedExecutor()
    side_progress, watch = Progress(), Progress()
    waiting = threading.get_ident()
    helped = threading.Event()
    done = []

    def stage():
        def chunk(index, s):
            if index == 0:
                assert helped.wait(10)  # the side holds its first chunk until the waiting thread took one
            elif threading.get_ident() == waiting and not helped.is_set():
                watch.cancel()  # the user cancels while the bake's thread runs a chunk of the side
                helped.set()
            done.append(index)
            return index
        map_chunks(executor, chunk, list(range(10_000)), side_progress)

    side = Beside(stage, side_progress, watch)
    side.start()
    with pytest.raises(Cancelled):
        side.wait(help=executor.help)
    assert not side.running and len(done) < 10_000
