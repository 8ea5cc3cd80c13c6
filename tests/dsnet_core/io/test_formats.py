"""The log-format registry: detection, the factory, and the errors for what is not a log."""

from pathlib import Path

import pytest

from dsnet_core.io.formats import UnknownLogFormatError, detect_format, format_names, open_log

ROOT = Path(__file__).resolve().parents[3]


def test_semantickitti_is_detected_and_opened(synth_log):
    assert "semantickitti" in format_names()
    assert detect_format(synth_log) == "semantickitti"
    reader = open_log(synth_log)
    assert reader.format == "semantickitti"
    assert reader.sequences() == ["00", "01"]
    assert reader.label_map is not None and reader.label_map.name == "semantic-kitti"


def test_unknown_layout_names_what_was_found_and_the_formats(tmp_path):
    (tmp_path / "scans").mkdir()
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(UnknownLogFormatError) as err:
        open_log(tmp_path)
    msg = str(err.value)
    assert str(tmp_path) in msg and "notes.txt" in msg and "scans/" in msg and "semantickitti" in msg


def test_missing_root_and_unknown_name(tmp_path):
    with pytest.raises(UnknownLogFormatError, match="no such file or folder"):
        detect_format(tmp_path / "nope")
    with pytest.raises(UnknownLogFormatError, match="unknown format 'velodyne-pcap'"):
        open_log(tmp_path, "velodyne-pcap")


def test_every_input_format_is_registered_and_named_in_the_error(tmp_path):
    assert format_names() == ["semantickitti", "nuscenes", "rosbag", "folder"]
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(UnknownLogFormatError) as err:
        detect_format(tmp_path)
    assert all(name in str(err.value) for name in format_names()) and "\n" not in str(err.value)


@pytest.mark.parametrize(("module", "suffix"), [("plyfile", ".ply"), ("laspy", ".las")])
def test_a_missing_extra_names_the_pip_install(tmp_path, module, suffix):
    # a fresh install without the 'formats' extra: the import fails, the error says what to install
    import subprocess
    import sys

    (tmp_path / f"000000{suffix}").write_bytes(b"not read: the library is missing")
    code = (
        f"import sys; sys.modules[{module!r}] = None\n"
        "from dsnet_core.io.folder import FolderReader\n"
        "from dsnet_core.errors import MissingExtraError\n"
        f"r = FolderReader({str(tmp_path)!r})\n"
        "try:\n    r.scan(r.frames(r.sequences()[0])[0])\n"
        "except MissingExtraError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert "pip install" in out.stdout and "[formats]" in out.stdout and module in out.stdout, out.stdout
