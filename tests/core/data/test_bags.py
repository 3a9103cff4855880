"""ROS 1 and ROS 2 bags written here with rosbags' writers read back as the frames they hold."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from vprsnn_export.data.frames import iter_frames  # noqa: E402
from vprsnn_export.errors import DataError  # noqa: E402

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"


def image_message(store, grey: np.ndarray, encoding: str, ros1: bool):
    """A sensor_msgs/Image of ``grey`` in ``encoding`` (rgb8/bgr8 repeat it in 3 channels; rows padded by 3 bytes)."""
    types = store.types
    stamp = types["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
    header = types["std_msgs/msg/Header"](**({"seq": 0} if ros1 else {}), stamp=stamp, frame_id="cam")
    pixels = grey if encoding == "mono8" else np.repeat(grey[:, :, None], 3, axis=2)
    rows = pixels.reshape(grey.shape[0], -1)
    padded = np.concatenate([rows, np.full((rows.shape[0], 3), 7, np.uint8)], axis=1)
    return types[IMAGE](
        header=header,
        height=grey.shape[0],
        width=grey.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=padded.shape[1],
        data=padded.ravel(),
    )


def compressed_message(store, grey: np.ndarray, ros1: bool, kind: str = "png"):
    """A sensor_msgs/CompressedImage of ``grey``: png, jpeg, or "cut" (a JPEG cut in half, its end marker kept: OpenCV decodes it partly)."""
    types = store.types
    stamp = types["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
    header = types["std_msgs/msg/Header"](**({"seq": 0} if ros1 else {}), stamp=stamp, frame_id="cam")
    data = cv2.imencode(".png" if kind == "png" else ".jpg", grey)[1].ravel()
    data = np.append(data[: data.size // 2], [0xFF, 0xD9]).astype(np.uint8) if kind == "cut" else data
    return types[COMPRESSED](header=header, format="png" if kind == "png" else "jpeg", data=data)


def write_bag(path: Path, topics: dict[str, list], ros1: bool = False, mcap: bool = False) -> Path:
    """A bag at ``path`` with ``topics``: name -> list of (kind, grey) with kind mono8/rgb8/bgr8/png (ROS 2:
    sqlite3 storage, or MCAP)."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    storage = StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=storage)
    with writer:
        for topic, frames in topics.items():
            msgtype = COMPRESSED if frames[0][0] in ("png", "jpeg", "cut") else IMAGE
            connection = writer.add_connection(topic, msgtype, typestore=store)
            for index, (kind, grey) in enumerate(frames):
                compressed = msgtype == COMPRESSED
                msg = (
                    compressed_message(store, grey, ros1, kind)
                    if compressed
                    else image_message(store, grey, kind, ros1)
                )
                data = store.serialize_ros1(msg, msgtype) if ros1 else store.serialize_cdr(msg, msgtype)
                writer.write(connection, 1_000_000 * (index + 1), data)
    return path


@pytest.fixture
def greys() -> list[np.ndarray]:
    return [np.random.default_rng(i).integers(0, 256, (6, 5), dtype=np.uint8) for i in range(4)]


@pytest.mark.parametrize(("ros1", "mcap"), [(False, False), (False, True), (True, False)], ids=["ros2", "mcap", "ros1"])
def test_a_bag_gives_back_its_frames_in_order(tmp_path, greys, ros1, mcap):
    kinds = ["mono8", "rgb8", "bgr8", "mono8"]
    frames = {"/cam": list(zip(kinds, greys, strict=True))}
    bag = write_bag(tmp_path / ("run.bag" if ros1 else "run"), frames, ros1, mcap)
    frames = list(iter_frames(bag))
    assert [name for name, _ in frames] == [f"{bag.name}#{i}" for i in range(4)]
    for (_, grey), expected in zip(frames, greys, strict=True):
        np.testing.assert_array_equal(grey, expected)  # grey repeated in 3 channels converts back to itself


def test_compressed_images_and_topic_choice(tmp_path, greys):
    bag = write_bag(tmp_path / "two", {"/cam": [("mono8", g) for g in greys], "/png": [("png", g) for g in greys[:2]]})
    with pytest.raises(DataError, match=r"image topics /cam, /png: give --topic"):
        iter_frames(bag)
    png = [grey for _, grey in iter_frames(bag, topic="/png")]
    assert len(png) == 2 and all(np.array_equal(a, b) for a, b in zip(png, greys, strict=False))
    with pytest.raises(DataError, match=r"no image topic '/depth' in this bag \(its image topics: /cam, /png\)"):
        iter_frames(bag, topic="/depth")
    with pytest.raises(DataError, match="--topic is for a ROS bag"):
        iter_frames(tmp_path, topic="/cam")


def test_a_damaged_bag_is_one_error(tmp_path):
    bag = tmp_path / "broken.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 64)
    with pytest.raises(DataError, match="cannot read this bag") as caught:
        list(iter_frames(bag))
    assert "\n" not in str(caught.value)


def test_a_compressed_frame_is_checked_against_the_memory_limit_before_decoding(tmp_path, greys):
    from vprsnn_export.errors import InvalidValueError
    from vprsnn_export.resources import set_memory_limit

    bag = write_bag(tmp_path / "png", {"/png": [("png", np.zeros((300, 400), np.uint8))]})
    try:
        set_memory_limit("100K")  # 4 x 400 x 300 = 469 KiB to decode
        with pytest.raises(InvalidValueError, match=r"decoded image 400 x 300, 468\.8 KiB\), over the limit"):
            list(iter_frames(bag))
    finally:
        set_memory_limit(None)
    assert next(iter_frames(bag))[1].shape == (300, 400)


def test_a_raw_frame_is_checked_against_the_memory_limit_before_decoding(tmp_path, monkeypatch):
    """Issue 31: a raw sensor_msgs/Image message is bounded like a compressed one: its bytes (deserialised, then
    converted: twice their size) against the memory limit before it is deserialised, one line naming the bag
    and the topic."""
    from rosbags.highlevel import AnyReader

    from vprsnn_export.errors import InvalidValueError
    from vprsnn_export.resources import set_memory_limit

    bag = write_bag(tmp_path / "raw", {"/cam": [("rgb8", np.zeros((300, 400), np.uint8))]})
    deserialised = []
    monkeypatch.setattr(AnyReader, "deserialize", lambda self, raw, t: deserialised.append(t))
    try:
        set_memory_limit("200K")  # 300 rows of 1203 bytes: 352 KiB, 705 KiB with the grey copy
        with pytest.raises(InvalidValueError) as caught:
            list(iter_frames(bag))
    finally:
        set_memory_limit(None)
    message = str(caught.value)
    assert f"message 0 of /cam in {bag}" in message and "over the limit of 200.0 KiB" in message, message
    assert "\n" not in message and deserialised == []  # refused before the message was deserialised
    monkeypatch.undo()
    assert next(iter_frames(bag))[1].shape == (300, 400)


def test_an_encoding_not_read_is_one_error(tmp_path, greys):
    bag = write_bag(tmp_path / "depth", {"/depth": [("mono16", greys[0])]})
    with pytest.raises(DataError, match=r"#0: image encoding 'mono16' is not read \(only mono8, rgb8"):
        list(iter_frames(bag))


def test_a_truncated_jpeg_frame_is_one_error(tmp_path, capfd):
    grey = np.random.default_rng(0).integers(0, 256, (64, 64), dtype=np.uint8)
    bag = write_bag(tmp_path / "jpeg", {"/jpeg": [("jpeg", grey), ("cut", grey)]})
    frames = iter_frames(bag)
    assert next(frames)[1].shape == (64, 64)
    with pytest.raises(
        DataError, match=r"#1: truncated or corrupt 'jpeg' image \(the decoder said: .*[Pp]remature end"
    ):
        next(frames)
    assert capfd.readouterr().err == ""  # libjpeg's own warning is captured, quoted in the error
