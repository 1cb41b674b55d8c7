"""`bench logs info|verify|import` through the top-level dispatcher."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.logs import from_arrays, read_dataset, write_dataset

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def _need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"{path} not found (the shared data folder lives outside the repo)")
    return path


@pytest.mark.parametrize(
    "argv",
    [
        ["logs"],
        ["logs", "--help"],
        ["logs", "info", "--help"],
        ["logs", "verify", "--help"],
        ["logs", "import", "--help"],
    ],
)
def test_help(argv, capsys):
    assert main(argv) == 0
    assert "usage: bench logs" in capsys.readouterr().out


def test_import_help_lists_keys(capsys):
    """The common keys, then one section per format with that format's keys (from their dataclasses)."""
    main(["logs", "import", "--help"])
    text = capsys.readouterr().out
    for key in ("out", "format", "fps", "task", "robot_type", "overwrite=false"):
        assert f"\n  {key} " in text, key
    for section, keys in [
        ("csv keys:", ("state", "action", "time", "episode", "delimiter=,")),
        ("mat keys", ("state", "action", "time", "velocity=false")),
        ("rlds keys", ("split=train", "state=observation/state", "action=action", "instruction=")),
    ]:
        part = text.split(section, 1)[1].split("\n\n", 1)[0]
        for key in keys:
            assert f"\n  {key}" in part, (section, key)


def test_info(tmp_path, capsys):
    ds = from_arrays(
        [{"observation.state": np.zeros((3, 2)), "action": np.zeros((3, 1))}] * 2,
        fps=15,
        names={"action": ["u"]},
        task="reach",
        robot_type="arm",
    )
    write_dataset(tmp_path / "d", ds)
    assert main(["logs", "info", str(tmp_path / "d")]) == 0
    text = capsys.readouterr().out
    assert "episodes  2  (frames 6; length 3..3" in text and "fps       15" in text
    assert "observation.state" in text and "float32" in text and "[2]" in text and "reach" in text


def _dataset(root: Path, video: bool = False) -> Path:
    eps = [
        {
            "observation.state": np.random.default_rng(e).normal(size=(20, 2)),
            "action": np.zeros((20, 1)),
            **({"observation.images.cam": np.full((20, 16, 16, 3), 40 * e, np.uint8)} if video else {}),
        }
        for e in range(3)
    ]
    write_dataset(root, from_arrays(eps, fps=10, video=video))
    return root


def _edit(path: Path, fn) -> None:
    data = bytearray(path.read_bytes())
    path.write_bytes(bytes(fn(data)))


DATA = "data/chunk-000/file-000.parquet"


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda d: d[: len(d) // 2], "not a readable parquet file (truncated?)"),  # truncated
        (lambda d: d[:-200] + b"\0" * 200, "not a readable parquet file (truncated?)"),  # garbage over the footer
        (lambda d: b"", "not a readable parquet file (truncated?)"),  # empty
        (None, "file is missing"),
    ],
    ids=["truncated", "garbage-footer", "empty", "missing"],
)
def test_info_reads_every_data_files_footer(tmp_path, capsys, damage, message):
    """`bench logs info` reads no frame, but a data file that is gone or not parquet is named (exit 2)."""
    root = _dataset(tmp_path / "d")
    assert main(["logs", "info", str(root)]) == 0
    assert "files     1 data file(s) (60 rows), 0 video file(s): footers read" in capsys.readouterr().out
    if damage is None:
        (root / DATA).unlink()
    else:
        _edit(root / DATA, damage)
    assert main(["logs", "info", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{root / DATA}: {message}" in err, err
    assert main(["logs", "verify", str(root)]) == 2
    assert f"{root / DATA}: {message}" in capsys.readouterr().err


def test_verify_reads_every_frame_info_only_the_footers(tmp_path, capsys):
    """Bytes spoiled inside a data page leave the footer intact: `info` passes, `verify` names the file."""
    import pyarrow.parquet as pq

    root = _dataset(tmp_path / "d")
    assert main(["logs", "verify", str(root)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"{root}: ok: 3 episodes, 60 frames; 1 data file(s) and 0 video file(s) read in full")
    page = pq.read_metadata(root / DATA).row_group(0).column(0).data_page_offset

    def spoil(d: bytearray) -> bytearray:
        d[page + 10 : page + 60] = b"\xff" * 50
        return d

    _edit(root / DATA, spoil)
    assert main(["logs", "info", str(root)]) == 0  # footers only: this damage is not visible there
    capsys.readouterr()
    assert main(["logs", "verify", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(root / DATA) in err and "corrupt" in err, err


def test_info_and_verify_check_video_files(tmp_path, capsys):
    root = _dataset(tmp_path / "v", video=True)
    assert main(["logs", "verify", str(root)]) == 0
    assert "1 data file(s) and 1 video file(s) read in full" in capsys.readouterr().out
    video = next((root / "videos").rglob("*.mp4"))
    video.write_bytes(b"")
    assert main(["logs", "info", str(root)]) == 2
    assert f"{video}: video file is empty" in capsys.readouterr().err


def test_import_csv(tmp_path, capsys):
    src = tmp_path / "log.csv"
    src.write_text("time,q,u\n" + "".join(f"{i * 0.01},{i},{-i}\n" for i in range(10)))
    out = tmp_path / "ds"
    assert main(["logs", "import", str(src), f"out={out}", "time=time", "state=[q]", "action=u", "task=wave"]) == 0
    assert "wrote" in capsys.readouterr().out
    ds = read_dataset(out)
    assert ds.fps == 100 and ds.tasks == ["wave"] and ds.features["action"]["names"] == ["u"]
    np.testing.assert_array_equal(ds.episodes[0].data["observation.state"][:, 0], np.arange(10, dtype=np.float32))
    # refuses to overwrite, then does with overwrite=true
    assert main(["logs", "import", str(src), f"out={out}", "time=time", "state=[q]"]) == 2
    assert "pass overwrite=true" in capsys.readouterr().err
    assert main(["logs", "import", str(src), f"out={out}", "time=time", "state=[q]", "overwrite=true"]) == 0


def test_import_mat_emps(tmp_path):
    src = _need(SHARED / "real" / "emps" / "DATA_EMPS.mat")
    assert (
        main(["logs", "import", str(src), f"out={tmp_path / 'e'}", "state=[qm]", "action=[vir]", "velocity=true"]) == 0
    )
    ds = read_dataset(tmp_path / "e")
    assert ds.features["observation.state"]["names"] == ["qm", "qm_dot"] and ds.fps == 1000


def test_import_rlds(tmp_path):
    src = _need(SHARED / "formats" / "rlds_toy" / "toy_rlds")
    assert main(["logs", "import", str(src), f"out={tmp_path / 'r'}", "fps=5"]) == 0  # format from the folder
    assert len(read_dataset(tmp_path / "r").episodes) == 3


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["logs", "import", "x.csv", "out=o", "split=train"],
            "unknown key 'split' (for format=csv); valid keys — all formats: out, format",
        ),
        (["logs", "import", "x.csv"], "missing key 'out'"),
        (["logs", "import", "x.bin", "out=o"], "cannot tell the format"),
        (["logs", "import", "x.csv", "out=o", "format=hdf5"], "format is 'hdf5'; valid: csv, mat, rlds"),
        (["logs", "info", "/nonexistent/dataset"], "dataset folder does not exist"),
        (
            ["logs", "inf", "x"],
            "unknown logs subcommand 'inf'; valid: info, verify, import, card, rank. Did you mean 'info'",
        ),
    ],
)
def test_errors_exit_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
