"""Measurements a build makes, shared by the workers of one run that build the same cell (bench.sims.build_memo):
the Lift observer's gripper range on a real robosuite arm, taken from another worker's build, gives the same
records as measuring it again."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from bench import api
from bench.execution.runner import MEMO_PREFIX, Worker, memo_folder
from bench.protocols.env import unwrap
from bench.records import comparable
from bench.sims.build_memo import building, remembered


def _counting():
    calls = []

    def measure():
        calls.append(1)
        return {"a": np.arange(3, dtype=np.float64) / 7, "b": np.array([len(calls)])}

    return calls, measure


def test_a_value_is_measured_once_per_cell_and_run_and_only_inside_a_build():
    calls, measure = _counting()
    assert remembered("x", measure)["b"][0] == 1 and remembered("x", measure)["b"][0] == 2  # no build: no memo
    with memo_folder() as folder:
        with building(folder, "Lift/Jaco/default"):
            first = remembered("x", measure)
        with building(folder, "Lift/Jaco/default"):  # another worker's build of the same cell
            again = remembered("x", measure)
        assert len(calls) == 3 and again.keys() == first.keys()
        assert all(np.array_equal(again[k], first[k]) and again[k].dtype == first[k].dtype for k in first)
        with building(folder, "Lift/XArm7/default"):  # another cell: measured for itself
            assert remembered("x", measure)["b"][0] == 4
        with building(folder, "Lift/Jaco/default"):  # another measurement of the same cell
            assert remembered("y", measure)["b"][0] == 5
        assert not [p for p in os.listdir(folder) if p.endswith(".tmp")]
    assert not os.path.exists(folder)  # the run's folder goes with the run
    with building(folder, "Lift/Jaco/default"):  # a folder this process cannot see: nothing shared
        assert remembered("x", measure)["b"][0] == 6 and not os.path.exists(folder)


@pytest.mark.parametrize("robot", ["Jaco"])  # three fingers: the longest measurement (~1.2 s)
def test_a_second_worker_takes_the_gripper_range_and_its_records_equal(tmp_path, robot, monkeypatch):
    pytest.importorskip("robosuite")
    from suites.lift import LiftObserver

    calls = []
    measure = LiftObserver._measure_gripper

    def counted(self):
        calls.append(1)
        return measure(self)

    monkeypatch.setattr(LiftObserver, "_measure_gripper", counted)
    cfg = api.RunConfig(suite="held_out_robots", policy="scripted", robots=[robot], episodes=2)
    p = api.plan(cfg)
    records = []
    with memo_folder() as folder:
        spec = dataclasses.replace(api.worker(p).spec, build_memo=folder)
        for job in p.jobs:  # each episode on a worker of its own: the first measures, the second reads
            w = Worker(spec)
            try:
                records.append(w.run(job))
                observer = unwrap(w.built(job)[0]).observer
                ranges = (observer._grip_c, observer._grip_inv_span)
            finally:
                w.close()
        assert len(calls) == 1
    plain = api.worker(p)  # no memo: every build measures
    try:
        alone = [plain.run(job) for job in p.jobs]
        observer = unwrap(plain.built(p.jobs[0])[0]).observer
        assert np.array_equal(observer._grip_c, ranges[0]) and np.array_equal(observer._grip_inv_span, ranges[1])
    finally:
        plain.close()
    assert len(calls) == 2
    assert all(r.error is None for r in records)
    assert [comparable(r) for r in records] == [comparable(r) for r in alone]


def test_the_folder_of_a_killed_run_goes_with_the_next_run(tmp_path):
    """A run killed with SIGKILL cannot remove its memo folder; the next one removes the folders of
    processes that are gone (and leaves those of live ones)."""
    import subprocess
    import sys
    import tempfile

    code = "from bench.execution.runner import memo_folder\nwith memo_folder() as f:\n    print(f, flush=True)\n    input()"
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    left = proc.stdout.readline().strip()
    proc.kill()
    proc.wait()
    assert os.path.isdir(left) and os.path.basename(left).startswith(f"{MEMO_PREFIX}{proc.pid}-")
    with memo_folder() as mine:
        assert not os.path.exists(left)
        with memo_folder() as nested:  # a live process's folder is kept
            assert os.path.isdir(mine) and os.path.isdir(nested)
    assert os.path.dirname(mine) == tempfile.gettempdir()
