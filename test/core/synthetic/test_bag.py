"""The bag reads back with the mcap library (the .mcap file) and with rosbags (both storages)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.synthetic import COMPRESSED_IMAGE_TOPIC, TOPICS, SynthConfig, generate_orchard
from fruitnerfpp_ros.errors import SynthError

from .conftest import SmallScene

_TYPES = {TOPICS['image']: 'sensor_msgs/msg/Image', TOPICS['camera_info']: 'sensor_msgs/msg/CameraInfo',
          TOPICS['pose']: 'geometry_msgs/msg/PoseStamped', TOPICS['instance_mask']: 'sensor_msgs/msg/Image',
          TOPICS['tf']: 'tf2_msgs/msg/TFMessage', TOPICS['tf_static']: 'tf2_msgs/msg/TFMessage'}


def test_mcap_library_reads_the_bag(small_scene: SmallScene) -> None:
    views = small_scene.config.views
    (mcap_file,) = small_scene.result.bag_path.glob('*.mcap')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with open(mcap_file, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        channels = {c.topic: (summary.schemas[c.schema_id].name, c.message_encoding)
                    for c in summary.channels.values()}
        assert channels == {topic: (msgtype, 'cdr') for topic, msgtype in _TYPES.items()}
        counts = {summary.channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}
        assert counts == {**{t: views for t in _TYPES}, TOPICS['tf_static']: 1}
        images = []
        for _, channel, message in reader.iter_messages(topics=[TOPICS['image']]):
            msg = typestore.deserialize_cdr(message.data, 'sensor_msgs/msg/Image')
            assert message.log_time == msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
            assert (msg.encoding, msg.height, msg.width, msg.step) == ('rgb8', 80, 96, 96 * 3)
            images.append(np.frombuffer(msg.data.tobytes(), np.uint8).reshape(80, 96, 3))
    # The bag's images are the dataset's images.
    import cv2
    tf = read_transforms(small_scene.result.dataset_dir)
    first = cv2.imread(str(small_scene.result.dataset_dir / tf.frames[0].file_path))[..., ::-1]
    np.testing.assert_array_equal(images[0], first)


def test_sqlite3_bag_reads_back_with_rosbags(tmp_path: Path) -> None:
    config = SynthConfig(fruit='plum', count=12, views=3, resolution=(40, 32), seed=1)
    result = generate_orchard(config, tmp_path / 'ds', bag=tmp_path / 'bag', bag_storage='sqlite3')
    assert list(result.bag_path.glob('*.db3'))
    with AnyReader([result.bag_path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == _TYPES
        masks = [reader.deserialize(raw, c.msgtype) for c, _, raw in
                 reader.messages([c for c in reader.connections if c.topic == TOPICS['instance_mask']])]
    assert len(masks) == 3 and all(m.encoding == 'mono16' and m.step == 80 for m in masks)
    ids = np.frombuffer(masks[0].data.tobytes(), '<u2')
    assert 0 < ids.max() <= 12


def test_bag_refuses_a_path_that_is_not_a_bag(tmp_path: Path) -> None:
    (tmp_path / 'notabag').mkdir()
    (tmp_path / 'notabag' / 'x.txt').write_text('keep me')
    config = SynthConfig(count=3, views=1, resolution=(16, 16))
    with pytest.raises(SynthError, match='not a rosbag2 directory'):
        generate_orchard(config, tmp_path / 'ds', bag=tmp_path / 'notabag')
    assert (tmp_path / 'notabag' / 'x.txt').read_text() == 'keep me'
    with pytest.raises(SynthError, match='unknown bag storage'):
        generate_orchard(config, tmp_path / 'ds', bag=tmp_path / 'b', bag_storage='rosbag1')
    # A previous bag is replaced.
    generate_orchard(config, tmp_path / 'ds', bag=tmp_path / 'b')
    generate_orchard(config, tmp_path / 'ds', bag=tmp_path / 'b')
    assert (tmp_path / 'b' / 'metadata.yaml').exists()


def test_jpeg_bag_in_the_odom_frame(tmp_path: Path) -> None:
    """--bag-image-format jpeg: CompressedImage on image_transport's topic, decodable by cv2.imdecode and by the
    node's conversions; masks stay raw mono16; --world-frame names the pose header and the /tf parent."""
    import cv2

    from fruitnerfpp_ros.nodes.conversions import camera_model_from_camera_info, image_from_msg

    config = SynthConfig(fruit='apple', count=10, views=3, resolution=(64, 48), seed=2, bag_image_format='jpeg',
                         bag_jpeg_quality=95, world_frame='odom', distortion=(-0.1, 0.01, 0.0, 0.0, 0.0))
    result = generate_orchard(config, tmp_path / 'ds', bag=tmp_path / 'bag')
    expected = {**_TYPES, COMPRESSED_IMAGE_TOPIC: 'sensor_msgs/msg/CompressedImage'}
    del expected[TOPICS['image']]
    assert COMPRESSED_IMAGE_TOPIC == '/camera/image_raw/compressed'
    tf = read_transforms(result.dataset_dir)
    with AnyReader([result.bag_path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == expected
        msgs: dict[str, list] = {}
        for conn, _, raw in reader.messages():
            msgs.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert len(msgs[COMPRESSED_IMAGE_TOPIC]) == 3
    for i, msg in enumerate(msgs[COMPRESSED_IMAGE_TOPIC]):
        assert msg.format == 'rgb8; jpeg compressed bgr8' and msg.header.frame_id == 'camera_optical'
        assert bytes(msg.data[:2]) == b'\xff\xd8'  # a JPEG stream
        bgr = cv2.imdecode(np.frombuffer(msg.data.tobytes(), np.uint8), cv2.IMREAD_COLOR)
        rgb = image_from_msg(msg, topic=COMPRESSED_IMAGE_TOPIC)
        truth = cv2.imread(str(result.dataset_dir / tf.frames[i].file_path))
        assert bgr.shape == truth.shape == (48, 64, 3)
        np.testing.assert_array_equal(rgb, bgr[..., ::-1])
        assert np.abs(bgr.astype(int) - truth).mean() < 8.0  # lossy (busy texture at 64 px), yet the same image
    for mask in msgs[TOPICS['instance_mask']]:
        assert mask.encoding == 'mono16'
    for pose in msgs[TOPICS['pose']]:
        assert pose.header.frame_id == 'odom'
    for tf_msg in msgs[TOPICS['tf']]:
        assert [(t.header.frame_id, t.child_frame_id) for t in tf_msg.transforms] == [('odom', 'base_link')]
    camera = camera_model_from_camera_info(msgs[TOPICS['camera_info']][0])
    assert camera.is_distorted and camera.distortion_model == 'plumb_bob'
    assert camera.intrinsics.cx == tf.intrinsics.cx and camera.intrinsics.fl_y == tf.intrinsics.fl_y
