"""A run folder that is a file, an output folder that is a file, an output file that is a folder:
one typed line naming the path, before anything is read or written (was: NotADirectoryError or
IsADirectoryError tracebacks, and a ``.tmp`` file left beside the dashboard)."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from flows.cli import app


def _run(*args: str):
    res = CliRunner().invoke(app, list(args), env={"COLUMNS": "250"})
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    return res


@pytest.mark.parametrize(
    "command",
    [
        ("status", "{f}"),
        ("export", "{f}", "--out", "{d}/out"),
        ("review", "export", "{f}", "--out", "{d}/out"),
        ("dashboard", "{f}", "--out", "{d}/dash.html"),
        ("label", "{d}/log", "--run", "{f}"),
    ],
    ids=lambda c: " ".join(c[:2]),
)
def test_a_run_folder_that_is_a_file_is_one_line(tmp_path, command):
    (tmp_path / "log").mkdir()
    run_file = tmp_path / "run.json"
    run_file.write_text("{}")
    if command[0] == "label":  # a log that opens: the run folder is what is wrong
        from tests.logs import make_log

        make_log(tmp_path / "log", ("00",), n_frames=2, n_ground=200)
    res = _run(*[part.format(f=run_file, d=tmp_path) for part in command])
    assert res.exit_code == 2, res.output
    assert res.output.count("\n") == 1 and "Traceback" not in res.output
    assert f"error: {run_file}: is a file, not a run folder" in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log", "run.json"]  # nothing written


@pytest.mark.parametrize(
    ("command", "option"),
    [
        (("export", "{run}", "--out", "{target}"), "--out"),
        (("review", "export", "{run}", "--out", "{target}"), "--out"),
        (("synth", "{target}", "--frames", "1"), "OUT"),
    ],
    ids=["export", "review export", "synth"],
)
def test_an_output_folder_that_is_a_file_is_one_line(tmp_path, command, option):
    target = tmp_path / "labels"
    target.write_text("not a folder")
    res = _run(*[p.format(run=tmp_path / "run", target=target) for p in command])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert res.output.strip() == (
        f"error: {target}: is a file, but {option} names the folder to write: give a folder"
    )
    assert target.read_text() == "not a folder"
    below = tmp_path / "labels" / "deeper"  # under a file: the file is named
    res = _run(*[p.format(run=tmp_path / "run", target=below) for p in command])
    assert res.exit_code == 2
    assert res.output.strip() == f"error: {target}: is a file, so {option} {below} cannot be written under it"


def test_a_dashboard_file_that_is_a_folder_is_one_line_and_leaves_nothing(tmp_path):
    out = tmp_path / "dash"
    out.mkdir()
    res = _run("dashboard", str(tmp_path / "run"), "--out", str(out))
    assert res.exit_code == 2 and "Traceback" not in res.output
    want = f"error: {out}: is a folder, but --out names the file to write: give a file name"
    assert res.output.strip() == want
    assert list(tmp_path.iterdir()) == [out] and list(out.iterdir()) == []  # no .tmp beside or inside


def test_a_file_inside_a_store_where_a_folder_belongs_is_named(tmp_path):
    from storage.errors import NotAFolderError
    from storage.fs import RootFS

    (tmp_path / "sequences").write_text("")  # a file where the store's folder of sequences belongs
    root = RootFS(tmp_path)
    root.check()  # the root itself is a folder
    with pytest.raises(NotAFolderError, match="sequences: is a file where the run store needs a folder"):
        root.read_bytes("sequences/00/ingest/manifest.json")
    with pytest.raises(NotAFolderError, match="sequences: is a file"):
        root.write_bytes("sequences/00/ingest/manifest.json", b"{}")
    assert root.read_bytes("other.json") is None and not root.exists("other.json")
