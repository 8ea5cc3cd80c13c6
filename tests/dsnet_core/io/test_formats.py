"""The log-format registry: detection, the factory, and the errors for what is not a log."""

from pathlib import Path

import numpy as np
import pytest

from dsnet_core.io.formats import FORMATS, UnknownLogFormatError, detect_format, open_log
from dsnet_core.io.reader import FrameRef

ROOT = Path(__file__).resolve().parents[3]


def test_semantickitti_is_detected_and_opened(synth_log):
    assert "semantickitti" in list(FORMATS)
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
    assert list(FORMATS) == ["semantickitti", "nuscenes", "rosbag", "folder"]
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(UnknownLogFormatError) as err:
        detect_format(tmp_path)
    assert all(name in str(err.value) for name in list(FORMATS)) and "\n" not in str(err.value)


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


def test_label_map_option_by_bundled_name_or_yaml_path(synth_log, tmp_path):
    # `--reader-option label_map=semantic-kitti` (documented) was an AttributeError in describe and ingest
    from dsnet_core.io.describe import summarize

    for value in ("semantic-kitti", str(ROOT / "dsnet_core" / "data" / "semantic-kitti.yaml")):
        reader = open_log(synth_log, options={"label_map": value})
        assert reader.label_map.name == "semantic-kitti"
        summary = summarize(reader, ["00"])
        assert summary.class_points["car"] > 0 and sum(summary.class_points.values()) == summary.points["00"]


@pytest.mark.parametrize(
    ("fmt", "options", "match"),
    [
        (
            "semantickitti",
            {"label_map": "nope"},
            r"reader option label_map='nope' is not allowed \(no bundled label map or YAML file 'nope'\); "
            r"the semantickitti reader takes a bundled label map \(panoptic-nuscenes, semantic-kitti\) or ",
        ),
        (
            "folder",
            {"bin_columns": "abc"},
            r"reader option bin_columns='abc' is not allowed; the folder reader takes 4 or 5",
        ),
        (
            "folder",
            {"bin_columns": 7},
            r"reader option bin_columns=7 is not allowed; the folder reader takes 4 or 5 ",
        ),
        (
            "folder",
            {"order": "random"},
            r"order='random' is not allowed; the folder reader takes name or time",
        ),
        (
            "folder",
            {"suffix": "txt"},
            r"suffix='txt' is not allowed; the folder reader takes one of .bin, .npy",
        ),
        (
            "folder",
            {"intensity": "linear"},
            r"intensity='linear' is not allowed; the folder reader takes one of auto, ",
        ),
        (
            "folder",
            {"pose_tolerance_s": -1},
            r"pose_tolerance_s=-1 is not allowed; the folder reader takes seconds",
        ),
        (
            "semantickitti",
            {"check_labels": "maybe"},
            r"check_labels='maybe' is not allowed; .* takes true or false",
        ),
        (
            "semantickitti",
            {"label_map": 5},
            r"label_map=5 is not allowed \(no bundled label map or YAML file '5'\)",
        ),
    ],
)
def test_a_bad_reader_option_value_is_one_line_naming_the_option(synth_log, tmp_path, fmt, options, match):
    from dsnet_core.errors import ConfigError

    root = synth_log
    if fmt == "folder":
        root = tmp_path / "scans"
        root.mkdir()
        np.arange(40, dtype=np.float32).tofile(root / "000000.bin")
    with pytest.raises(ConfigError, match=match) as err:
        open_log(root, fmt, options)
    assert str(err.value).startswith(f"{root}: ") and "\n" not in str(err.value)


def test_a_label_map_yaml_that_is_broken_is_named(synth_log, tmp_path):
    from dsnet_core.errors import ConfigError

    bad = tmp_path / "map.yaml"
    bad.write_text("labels: {0: unlabeled}\n")
    with pytest.raises(
        ConfigError, match=rf"label_map='{bad}' is not allowed \({bad}: missing required key 'learning_map'\)"
    ):
        open_log(synth_log, options={"label_map": str(bad)})


def test_good_option_values_reach_the_reader(tmp_path):
    root = tmp_path / "scans"
    root.mkdir()
    np.arange(40, dtype=np.float32).tofile(root / "000000.bin")  # 40 floats: 4 or 5 columns both fit
    assert open_log(root, "folder", {"bin_columns": 5}).scan(
        FrameRef("scans", "000000", 0, root / "000000.bin")
    ).shape == (8, 4)
    reader = open_log(
        root, "folder", {"bin_columns": "4", "suffix": "BIN", "order": None, "pose_tolerance_s": 0}
    )
    assert reader._bin_columns == 4 and reader.suffix == ".bin" and reader.order == "name"
    assert reader.scan(reader.frames("scans")[0]).shape == (10, 4)


def test_every_declared_option_is_a_keyword_of_its_reader():
    import inspect

    from dsnet_core.io import folder, nuscenes_reader, pointfiles, rosbag, semantickitti
    from dsnet_core.io.formats import FORMATS, SCAN_SUFFIXES

    readers = {
        "semantickitti": semantickitti.SemanticKittiReader,
        "nuscenes": nuscenes_reader.NuScenesReader,
        "rosbag": rosbag.RosbagReader,
        "folder": folder.FolderReader,
    }
    for name, fmt in FORMATS.items():
        params = set(inspect.signature(readers[name]).parameters) - {"root"}
        assert {o.name for o in fmt.options} == params, name
    assert SCAN_SUFFIXES == pointfiles.SUFFIXES


def test_options_are_checked_without_opening_the_log(tmp_path):
    from dsnet_core.errors import ConfigError
    from dsnet_core.io.formats import check_reader_options

    (tmp_path / "v1.0-mini").mkdir()
    (tmp_path / "v1.0-mini" / "sample_data.json").write_text("not read")  # detected, never parsed
    assert check_reader_options(tmp_path, options={"sweeps": "yes"}) == ("nuscenes", {"sweeps": True})
    with pytest.raises(
        ConfigError, match="sweeps='maybe' is not allowed; the nuscenes reader takes true or false"
    ):
        check_reader_options(tmp_path, "auto", {"sweeps": "maybe"})
