"""bench check: split hygiene catches overlaps and seed wrap-around; clean suites pass."""
import pytest

from bench.check import check_cells, check_manifest, check_seeds
from bench.cli import main
from bench.suite import NOMINAL, Cell, Job, Suite


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
    class Leaky(Suite):
        name = "leaky"
        manifest = {"robots": {"seen": ["Panda"], "unseen": ["Panda"]}}

        def all_cells(self):
            return [Cell(self.name, "Lift", "Panda", "default", "seen")]

    from bench import registry

    monkeypatch.setattr(registry, "make_suite", lambda name: Leaky())
    assert main(["run", "suite=leaky", f"out={tmp_path}", "policy=random"]) == 2
    assert "listed as both seen and unseen" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


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
