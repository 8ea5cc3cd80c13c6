import numpy as np
import pytest

from dsnet_core.errors import ConfigError
from dsnet_core.labels import load_label_map


def test_semantic_kitti_map_derivations():
    lm = load_label_map("semantic-kitti")
    assert lm.num_classes == 20
    assert lm.things == tuple(range(1, 9))
    assert lm.stuff == tuple(range(9, 20))
    assert lm.class_names[1] == "car" and lm.class_names[19] == "traffic-sign"
    assert lm.min_points == 50
    assert lm.split["valid"] == [8]
    # moving classes fold onto their static train id; lane marking onto road
    assert lm.to_train(np.array([252, 254, 60, 40, 0, 52])).tolist() == [1, 6, 9, 9, 0, 0]
    # learning_map_inv round-trips every train id
    train = np.arange(20)
    assert (lm.to_train(lm.to_raw(train)) == train).all()
    assert lm.is_thing().sum() == 8


def test_unknown_raw_id_is_rejected():
    lm = load_label_map("semantic-kitti")
    with pytest.raises(ValueError, match="not in the semantic-kitti label map"):
        lm.to_train(np.array([10, 12]))
    with pytest.raises(ValueError, match=r"\[400\]"):
        lm.to_train(np.array([400]))


def test_panoptic_nuscenes_map():
    lm = load_label_map("panoptic-nuscenes")
    assert lm.num_classes == 17
    assert lm.things == tuple(range(1, 11)) and lm.stuff == tuple(range(11, 17))
    assert lm.class_names[4] == "car" and lm.class_names[16] == "vegetation"
    assert lm.to_train(np.array([17, 2, 31, 24])).tolist() == [4, 7, 0, 11]
    assert lm.min_points == 15


def test_custom_yaml_and_errors(tmp_path):
    f = tmp_path / "tiny.yaml"
    f.write_text("labels: {0: unlabeled, 5: thing}\nlearning_map: {0: 0, 5: 1}\nthings: [1]\n")
    lm = load_label_map(f)
    assert lm.class_names == ("unlabeled", "thing")
    with pytest.raises(ConfigError, match="not found"):
        load_label_map(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("labels: {0: x}\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: missing required key 'learning_map'"):
        load_label_map(bad)


def _write(tmp_path, text: str):
    f = tmp_path / "map.yaml"
    f.write_text(text)
    return f


BASE = "labels: {0: unlabeled, 5: a, 6: b}\nthings: [1]\n"


def test_train_id_typo_is_refused_not_a_1000_class_map(tmp_path):
    f = _write(tmp_path, BASE + "learning_map: {0: 0, 5: 1, 6: 999}\n")
    with pytest.raises(ConfigError, match=r"map\.yaml: .*missing \[2, 3, .*raw id 6 to train id 999"):
        load_label_map(f)
    f = _write(tmp_path, BASE + "learning_map: {0: 0, 5: 1, 6: 999}\nlearning_map_inv: {0: 0, 1: 5}\n")
    with pytest.raises(ConfigError, match=r"map\.yaml: learning_map sends raw id 6 to train id 999"):
        load_label_map(f)
    f = _write(tmp_path, BASE + "learning_map: {0: 0, 5: 1, 6: 2}\nthings: [7]\n")
    with pytest.raises(ConfigError, match=r"map\.yaml: 'things' has train id 7, outside 0\.\.2"):
        load_label_map(f)


@pytest.mark.parametrize(
    "ignore, expected", [("[0, 2]", (0, 2)), ("{0: true, 1: false, 2: true}", (0, 2)), ("[]", (0,))]
)
def test_learning_ignore_as_list_or_mapping(tmp_path, ignore, expected):
    f = _write(tmp_path, BASE + f"learning_map: {{0: 0, 5: 1, 6: 2}}\nlearning_ignore: {ignore}\n")
    assert load_label_map(f).ignore == expected


def test_learning_ignore_errors(tmp_path):
    f = _write(tmp_path, BASE + "learning_map: {0: 0, 5: 1, 6: 2}\nlearning_ignore: [0, 5]\n")
    with pytest.raises(ConfigError, match=r"map\.yaml: 'learning_ignore' has train id 5, outside 0\.\.2"):
        load_label_map(f)
    f = _write(tmp_path, BASE + "learning_map: {0: 0, 5: 1, 6: 2}\nlearning_ignore: yes please\n")
    with pytest.raises(ConfigError, match=r"map\.yaml: 'learning_ignore' must map train ids"):
        load_label_map(f)


def test_bundled_maps_ignore_class_zero():
    assert load_label_map("semantic-kitti").ignore == (0,)
    assert load_label_map("panoptic-nuscenes").ignore == (0,)


def test_binary_file_is_a_config_error(tmp_path):
    f = tmp_path / "map.yaml"
    f.write_bytes(b"labels: \xff\xfe\x00")
    with pytest.raises(ConfigError, match=r"map\.yaml: not a text file"):
        load_label_map(f)


def test_track_groups(tmp_path):
    lm = load_label_map("semantic-kitti")
    assert lm.track_groups == ((1, 4, 5), (2, 7), (3, 8), (6,))
    g = lm.track_group_of()
    assert g[1] == g[4] == g[5] == 0 and g[2] == g[7] == 1 and g[6] == 3
    assert len(set(g[[0, *range(9, 20)]].tolist())) == 12  # every other class alone
    base = (
        "labels: {0: u, 10: car, 30: person, 40: road}\n"
        "learning_map: {0: 0, 10: 1, 30: 2, 40: 3}\nthings: [1, 2]\n"
    )
    for groups, msg in (
        ("[[1, 2], [2]]", "more than one of 'track_groups'"),
        ("[[1, 3]]", "not things: \\[3\\]"),
        ("[car]", "must be a list of lists of train ids"),
    ):
        path = tmp_path / "m.yaml"
        path.write_text(base + f"track_groups: {groups}\n")
        with pytest.raises(ConfigError, match=msg):
            load_label_map(path)
    path.write_text(base)
    assert len(set(load_label_map(path).track_group_of().tolist())) == 4  # each class alone


def test_ground_classes(tmp_path):
    kitti, nusc = load_label_map("semantic-kitti"), load_label_map("panoptic-nuscenes")
    assert [kitti.class_names[i] for i in kitti.ground] == [
        "road",
        "parking",
        "sidewalk",
        "other-ground",
        "terrain",
    ]
    assert [nusc.class_names[i] for i in nusc.ground] == [
        "driveable_surface",
        "other_flat",
        "sidewalk",
        "terrain",
    ]
    base = "labels: {0: u, 10: car, 40: road}\nlearning_map: {0: 0, 10: 1, 40: 2}\nthings: [1]\n"
    path = tmp_path / "m.yaml"
    path.write_text(base)
    assert load_label_map(path).ground == ()  # a map that says nothing of the ground
    for ground, msg in (("[1]", "'ground' names thing ids \\[1\\]"), ("[5]", "'ground' has train id 5")):
        path.write_text(base + f"ground: {ground}\n")
        with pytest.raises(ConfigError, match=msg):
            load_label_map(path)
