"""bench check: split hygiene catches overlaps and seed wrap-around; clean suites pass."""

import pytest

from bench.cli import main
from bench.execution.check import check_cells, check_manifest, check_seeds
from bench.protocols.suite import NOMINAL, Cell, Job


def test_manifest_overlap_and_duplicates():
    probs = check_manifest({"robots": {"seen": ["A", "B", "B"], "unseen": ["B", "C"]}}, "m")
    msgs = [p.message for p in probs]
    assert any("['B'] listed as both seen and unseen" in m for m in msgs)
    assert any("listed twice in seen" in m for m in msgs)
    assert check_manifest({"robots": {"seen": ["A"], "unseen": ["C"]}}) == []


def test_cell_split_must_match_manifest():
    manifest = {"robots": {"seen": ["A"], "unseen": ["B"]}}
    bad = [Cell("s", "T", "B", "e", "seen")]
    assert "marked seen but robots 'B' is unseen" in check_cells(bad, manifest)[0].message
    assert check_cells([Cell("s", "T", "A", "e", "seen"), Cell("s", "T", "B", "e", "unseen")], manifest) == []


def test_repeated_seeds():
    cell = Cell("s", "T", "A", "e", "seen")
    jobs = [Job(cell, NOMINAL, 0, 5), Job(cell, NOMINAL, 1, 5)]
    assert check_seeds(jobs)[0].kind == "seeds"


def test_run_refuses_a_dirty_split(tmp_path, capsys, monkeypatch):
    (tmp_path / "leaky_suite.py").write_text(
        "from tests.toy_suite import ToySuite\n\n\n"
        "class Leaky(ToySuite):\n"
        "    name = 'leaky'\n"
        "    manifest = {'robots': {'seen': ['a', 'b'], 'unseen': ['a', 'c']}}\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "runs"
    assert main(["run", "suite=leaky_suite:Leaky", f"out={out}"]) == 2
    assert "listed as both seen and unseen" in capsys.readouterr().err
    assert not out.exists()


def test_check_verifies_the_suite_contract(tmp_path, capsys, monkeypatch):
    (tmp_path / "broken_suite.py").write_text(
        "from tests.toy_suite import ToySuite\n\n\n"
        "class Broken(ToySuite):\n"
        "    name = 'broken'\n"
        "    default_metric = 'speed'\n"
        "    capabilities = frozenset({'expert', 'teleport'})\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["check", "suite=broken_suite:Broken", "states=false"]) == 2
    out = capsys.readouterr().out
    assert "default_metric 'speed' is not one of success_once, success_at_end, return" in out
    assert "capabilities ['teleport'] are not known; valid: expert" in out
    assert main(["check", "suite=tests.toy_suite:ToySuite"]) == 0
    out = capsys.readouterr().out
    assert "contract on reach/a/line: ok" in out and "clean" in out


def test_check_passes_suite_keys_and_skips_suites_that_need_them(capsys):
    assert main(["check", "suite=tests.toy_suite:ToySuite", "goal=0.2", "contract=false", "states=false"]) == 0
    assert main(["check", "suite=tests.toy_suite:ToySuite", "goal=far"]) == 2
    assert "bad value for 'goal'" in capsys.readouterr().err


def test_metaworld_ml25_overlap_is_caught(capsys):
    pytest.importorskip("metaworld")
    assert main(["check", "manifest=metaworld:ML25"]) == 2
    assert "basketball-v3" in capsys.readouterr().out
    assert main(["check", "manifest=metaworld:ML10"]) == 0


def test_injected_seed_wraparound_is_caught_and_clean_suite_passes(capsys):
    pytest.importorskip("robosuite")
    args = ["check", "suite=held_out_robots", "robots=[Panda]", "episodes=3", "contract=false"]
    assert main(args + ["wrap_seeds=2"]) == 2
    assert "[wraparound]" in capsys.readouterr().out
    assert main(args) == 0
    assert "clean" in capsys.readouterr().out


def test_contract_on_robosuite_cell(capsys):
    pytest.importorskip("robosuite")
    assert main(["check", "suite=held_out_robots", "robots=[UR5e]", "states=false"]) == 0
    assert "contract on Lift/UR5e/default: ok" in capsys.readouterr().out
