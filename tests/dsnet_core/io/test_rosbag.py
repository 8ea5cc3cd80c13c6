"""ROS 2 bags written by the rosbags writer (sqlite3 and MCAP) read back as the SemanticKITTI
path reads the same log; fields by name and datatype, organised clouds, NaN returns, tf poses."""

from __future__ import annotations

import numpy as np
import pytest

from dsnet_core.errors import BagFormatError, IntensityFormatError, PoseFormatError
from dsnet_core.io.formats import detect_format, open_log
from dsnet_core.io.rosbag import RosbagReader
from tests.dsnet_core.io import encode
from tests.dsnet_core.io.compare import assert_same_log

EPOCH = encode.BAG_EPOCH_NS * 1e-9


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_reads_as_the_semantickitti_path(storage, quantised, tmp_path):
    ref = quantised("unit")
    bag = encode.write_bag(ref, tmp_path / "drive", storage)
    assert detect_format(bag) == "rosbag"
    reader = open_log(bag)
    assert reader.format == "rosbag" and reader.sequences() == ["drive"]
    assert reader.intensity_convention("drive") == "unit" and reader.fixed_frame_of("drive") == "odom"
    assert_same_log(reader, ref, times_offset=EPOCH)
    frames = reader.frames("drive")
    assert frames[0].frame_id == f"{encode.bag_ns(ref.timestamp(ref.frames('00')[0])):019d}"
    assert reader.cloud_frame(frames[0]) == "velodyne" and reader.dropped_points(frames[0]) == 0


def test_bare_storage_file_and_folder_of_bags(quantised, tmp_path):
    ref = quantised("unit")
    encode.write_bag(ref, tmp_path / "bags" / "b", "mcap")
    encode.write_bag(ref, tmp_path / "bags" / "a", "sqlite3")
    reader = open_log(tmp_path / "bags")
    assert reader.format == "rosbag" and reader.sequences() == ["a", "b"]
    mcap = next((tmp_path / "bags" / "b").glob("*.mcap"))
    single = RosbagReader(mcap)
    assert single.sequences() == [mcap.stem]
    assert np.array_equal(single.scan(single.frames(mcap.stem)[2]), ref.scan(ref.frames("00")[2]))


def test_organised_cloud_with_nan_returns(quantised, tmp_path):
    ref = quantised("unit")
    reader = RosbagReader(encode.write_bag(ref, tmp_path / "org", organised=True, nan_every=7))
    assert_same_log(reader, ref, times_offset=EPOCH)
    for f, g in zip(reader.frames("org"), ref.frames("00"), strict=True):
        n = len(ref.scan(g))
        assert reader.dropped_points(f) == n // 7 + (n + n // 7) % 2


def test_uint16_reflectivity_and_map_frame(quantised, tmp_path):
    ref = quantised("uint16")
    reader = RosbagReader(encode.write_bag(ref, tmp_path / "os", intensity="uint16", tf="map"))
    assert reader.intensity_convention("os") == "uint16" and reader.fixed_frame_of("os") == "map"
    assert_same_log(reader, ref, times_offset=EPOCH)


def test_no_intensity_and_no_tf(quantised, tmp_path):
    ref = quantised("none")
    reader = RosbagReader(encode.write_bag(ref, tmp_path / "bare", intensity=None, tf=None))
    assert reader.intensity_convention("bare") == "none"
    frame = reader.frames("bare")[0]
    assert np.array_equal(reader.scan(frame), ref.scan(ref.frames("00")[0]))
    assert reader.pose(frame) is None and reader.poses("bare") is None


def test_fixed_frame_option(quantised, tmp_path):
    bag = encode.write_bag(quantised("unit"), tmp_path / "d")
    assert RosbagReader(bag, fixed_frame="base_link").pose(RosbagReader(bag).frames("d")[0]) is not None
    reader = RosbagReader(bag, fixed_frame="earth")
    with pytest.raises(
        PoseFormatError, match=r"has no tf frame 'earth' \(tf frames: base_link, odom, velodyne\)"
    ):
        reader.poses("d")


def test_tf_is_interpolated_at_the_cloud_stamp(quantised, tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ref = quantised("unit")
    src = encode.write_bag(ref, tmp_path / "src", tf=None)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    times = [encode.bag_ns(ref.timestamp(f)) for f in ref.frames("00")]
    out = tmp_path / "interp"
    from rosbags.highlevel import AnyReader

    with AnyReader([src], default_typestore=ts) as r, Writer(out, version=9) as w:
        conn = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        for _, t, raw in r.messages():
            w.write(conn, t, raw)
        # odom -> velodyne moving at 3 m/s along y, sampled 1 s before and after the clouds
        for stamp, y in (
            (times[0] - 10**9, 0.0),
            (times[-1] + 10**9, 3.0 * ((times[-1] - times[0]) * 1e-9 + 2)),
        ):
            tr = T["geometry_msgs/msg/TransformStamped"](
                header=T["std_msgs/msg/Header"](
                    stamp=T["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9),
                    frame_id="odom",
                ),
                child_frame_id="velodyne",
                transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](x=0.0, y=y, z=0.0),
                    rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                ),
            )
            msg = T["tf2_msgs/msg/TFMessage"](transforms=[tr])
            w.write(c_tf, stamp, ts.serialize_cdr(msg, "tf2_msgs/msg/TFMessage"))
    poses = RosbagReader(out).poses("interp")
    expect = 3.0 * ((np.array(times) - times[0]) * 1e-9 + 1)
    np.testing.assert_allclose(poses[:, 1, 3], expect, atol=1e-6)
    late = RosbagReader(out, tf_tolerance_s=0.05)
    late._index("interp").tf._edges["velodyne"].times[-1] = times[-1] * 1e-9 - 0.5
    with pytest.raises(PoseFormatError, match=r"no transform odom <- velodyne for frame 2 .*tf covers"):
        late.pose(late.frames("interp")[2])


def test_bag_without_pointcloud2(quantised, tmp_path):
    bag = encode.write_bag(quantised("unit"), tmp_path / "tfonly", cloud=False)
    reader = RosbagReader(bag)
    with pytest.raises(
        BagFormatError, match=r"has no sensor_msgs/msg/PointCloud2 topic \(topics: /tf .*\)"
    ) as err:
        reader.frames("tfonly")
    assert str(err.value).startswith(str(bag)) and "\n" not in str(err.value)


def test_topic_choice(quantised, tmp_path):
    bag = encode.write_bag(quantised("unit"), tmp_path / "two", extra_topic="/lidar/front")
    with pytest.raises(
        BagFormatError, match=r"several PointCloud2 topics \(/lidar/front, /points\); choose one"
    ):
        RosbagReader(bag).frames("two")
    with pytest.raises(
        BagFormatError, match=r"no PointCloud2 topic '/nope' \(PointCloud2 topics: /lidar/front"
    ):
        RosbagReader(bag, topic="/nope").frames("two")
    assert len(RosbagReader(bag, topic="/lidar/front").frames("two")) == 3


def test_intensity_datatype_not_supported(quantised, tmp_path):
    bag = encode.write_bag(quantised("none"), tmp_path / "i32", intensity="int32")
    reader = RosbagReader(bag)
    with pytest.raises(IntensityFormatError, match="intensity column has type int32") as err:
        reader.scan(reader.frames("i32")[0])
    assert str(err.value).startswith(f"{bag} [/points @ ") and "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("layout", "match"),
    [
        (
            "half_width",
            r"cloud rows hold \d+ bytes past width \d+ × point_step 16 \(room for \d+ more points\)",
        ),
        (
            "short_row_step",
            r"cloud data has \d+ bytes.*, its layout height 1 × row_step \d+ = \d+ \(1 × \d+ points\)",
        ),
        ("wide", r"cloud rows of width \d+ × point_step 16 = \d+ bytes do not fit in row_step \d+"),
    ],
)
def test_a_cloud_layout_that_covers_part_of_its_data_is_refused(quantised, tmp_path, layout, match):
    # width × height covering half the data used to read half the points without a word
    ref = quantised("unit")
    bag = encode.write_bag(ref, tmp_path / "half", layout=layout)
    reader = RosbagReader(bag)
    frame = reader.frames("half")[1]
    with pytest.raises(BagFormatError, match=match) as err:
        reader.scan(frame)
    stamp = encode.bag_ns(ref.timestamp(ref.frames("00")[1]))
    assert str(err.value).startswith(f"{bag} [/points @ {stamp:019d}]: "), err.value
    assert "\n" not in str(err.value)


def test_zero_row_padding_is_accepted(quantised, tmp_path):
    # organised clouds with 8 zero bytes after each row (alignment padding) read as before
    ref = quantised("unit")
    reader = RosbagReader(encode.write_bag(ref, tmp_path / "pad", organised=True))
    assert_same_log(reader, ref, times_offset=EPOCH)


def test_clouds_in_two_frames_without_tf_are_named_and_refused(quantised, tmp_path):
    ref = quantised("unit")
    bag = encode.write_bag(ref, tmp_path / "two", tf=None, frame_ids=("velodyne", "rear"))
    reader = RosbagReader(bag)
    assert reader.cloud_frames("two") == {"velodyne": 2, "rear": 1}
    assert (
        reader.sensor_fields("two") == "x y z intensity (PointCloud2 /points, 2 frames: velodyne ×2, rear ×1)"
    )
    want = (
        r"clouds on /points are in 2 frames \(velodyne ×2, rear ×1\) and no tf relates them to a fixed "
        r"frame \(tf frames: none\): their points cannot be put in one frame"
    )
    with pytest.raises(PoseFormatError, match=want) as err:
        reader.poses("two")
    assert str(err.value).startswith(f"{bag}: ") and "\n" not in str(err.value)
    for frame in reader.frames("two"):  # each frame's pose: what ingest records or refuses
        with pytest.raises(PoseFormatError, match=want):
            reader.pose(frame)
    # the scans themselves still read (a topic of one sensor frame without tf has no poses at all)
    assert np.array_equal(reader.scan(reader.frames("two")[2]), ref.scan(ref.frames("00")[2]))
    one = RosbagReader(encode.write_bag(ref, tmp_path / "one", tf=None))
    assert one.cloud_frames("one") == {"velodyne": 3} and one.poses("one") is None


def test_clouds_in_two_frames_with_tf_each_get_their_pose(quantised, tmp_path):
    ref = quantised("unit")
    bag = encode.write_bag(ref, tmp_path / "two", frame_ids=("velodyne", "rear"))
    reader = RosbagReader(bag)
    assert reader.pose_source("two") == "tf odom -> velodyne, rear"
    assert reader.sensor_fields("two").endswith("2 frames: velodyne ×2, rear ×1)")
    np.testing.assert_allclose(reader.poses("two"), ref.poses("00"), rtol=0, atol=1e-9)
    lone = encode.write_bag(ref, tmp_path / "lone", tf=None, frame_ids=("a", "b"))
    with pytest.raises(PoseFormatError, match=r"has no tf frame 'odom' \(tf frames: none\)"):
        RosbagReader(lone, fixed_frame="odom").poses("lone")
