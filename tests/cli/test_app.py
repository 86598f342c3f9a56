"""The command line: outputs, one-line errors, no partial files."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from railwatch.cli import main


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(args)
    out, err = capsys.readouterr()
    return rc, out, err


def test_generate_writes_a_loadable_file(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "s3.npz"
    rc, _, _ = run(["-q", "generate", "--stage", "3", "--n", "40", "--seed", "2", "--out",
                    str(out), "--components"], capsys)
    assert rc == 0
    with np.load(out) as f:
        assert f["X"].shape == (40, 200, 2) and f["y"].sum() == 4
        assert json.loads(str(f["meta"]))["seed"] == 2 and "nuisance" in f.files


@pytest.mark.parametrize(
    ("args", "rc", "needle"),
    [
        (["generate", "--stage", "9", "--out", "{d}/a.npz"], 2, "'--stage'"),
        (["generate", "--stage", "0", "--out", "{d}/a.npz"], 2, "1<=x<=8"),
        (["generate", "--stage", "2", "--n", "0", "--out", "{d}/a.npz"], 2, "'--n'"),
        (["generate", "--stage", "2", "--out", "{d}/missing/a.npz"], 1, "does not exist"),
        (["generate", "--stage", "2", "--out", "{d}"], 2, "is a directory"),
        (["generate", "--stage", "2", "--out", "{d}/a.npz", "--colour"], 2, "No such option"),
        (["generate", "--out", "{d}/a.npz"], 2, "--stage"),
        (["frobnicate"], 2, "No such command"),
        (["figure", "stages", "--out", "{d}/nope/f.png"], 1, "does not exist"),
    ],
)
def test_bad_input_gives_one_line_and_nonzero_exit(  # type: ignore[no-untyped-def]
    args, rc, needle, tmp_path, capsys
) -> None:
    code, out, err = run([a.format(d=tmp_path) for a in args], capsys)
    assert code == rc
    assert err.count("\n") == 1 and err.startswith("railwatch: error:") and needle in err
    assert "Traceback" not in err + out
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_unwritable_folder(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    import os

    if os.access(locked, os.W_OK):
        pytest.skip("running as a user that can write anywhere")
    code, _, err = run(["generate", "--stage", "1", "--out", str(locked / "a.npz")], capsys)
    assert code == 1 and "not writable" in err


def test_failure_while_writing_leaves_nothing_and_keeps_old_file(  # type: ignore[no-untyped-def]
    tmp_path, capsys, monkeypatch
) -> None:
    out = tmp_path / "a.npz"
    out.write_bytes(b"previous result")

    def broken_savez(fh, **arrays):  # type: ignore[no-untyped-def]
        fh.write(b"half")
        raise OSError("No space left on device")

    monkeypatch.setattr(np, "savez", broken_savez)
    code, _, err = run(["generate", "--stage", "1", "--n", "10", "--out", str(out)], capsys)
    assert code == 1 and "No space left" in err and err.count("\n") == 1
    assert out.read_bytes() == b"previous result"
    assert [p.name for p in tmp_path.iterdir()] == ["a.npz"]


def test_every_command_has_help(capsys) -> None:  # type: ignore[no-untyped-def]
    for args in (["--help"], ["generate", "--help"], ["figure", "--help"],
                 ["figure", "stages", "--help"]):
        code, out, _ = run(args, capsys)
        assert code == 0 and "Usage:" in out
    _, out, _ = run(["generate", "--help"], capsys)
    for option in ("--stage", "--n", "--seed", "--out", "--components", "--fs"):
        assert option in out


def test_figure_stages(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "stages.png"
    code, _, _ = run(["figure", "stages", "--out", str(out)], capsys)
    assert code == 0 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_installed_entry_point_runs() -> None:
    done = subprocess.run([sys.executable, "-m", "railwatch.cli", "generate", "--stage", "11",
                           "--out", "x.npz"], capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.count("\n") == 1
