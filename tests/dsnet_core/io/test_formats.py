"""The log-format registry: detection, the factory, and the errors for what is not a log."""

import pytest

from dsnet_core.io.formats import UnknownLogFormatError, detect_format, format_names, open_log


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
