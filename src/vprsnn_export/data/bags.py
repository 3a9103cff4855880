"""Frames from the image topic of a ROS 1 bag (``.bag``) or a ROS 2 bag (a folder with ``metadata.yaml``).

Read with the pure-Python ``rosbags`` library (no ROS install) in the bag's time order, one frame per message of
the bag's one image topic (with several, ``topic`` names one), named ``<bag>#<index>``:

* ``sensor_msgs/msg/Image`` in ``mono8``, ``rgb8``, ``bgr8``, ``rgba8`` or ``bgra8`` (rows of ``step`` bytes,
  padding dropped; colour to grey with OpenCV's weights), its size checked against the memory limit before it
  is deserialised (``2 n`` bytes for a message of ``n``: its data, then the converted pixels);
* ``sensor_msgs/msg/CompressedImage`` (PNG or JPEG bytes), decoded like an image file, its header checked
  first (:func:`~vprsnn_export.data.preprocess.decode_checked`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..resources import check_memory, single_need
from .preprocess import decode_checked

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
#: ROS encoding -> the OpenCV conversion to grey (by name: OpenCV loads only when a frame is converted)
ENCODINGS = {"mono8": None, "rgb8": "COLOR_RGB2GRAY", "bgr8": "COLOR_BGR2GRAY"}
ENCODINGS |= {"rgba8": "COLOR_RGBA2GRAY", "bgra8": "COLOR_BGRA2GRAY"}
BAG_SUFFIX = ".bag"
SMALLER = "a smaller image would"
ROS2_METADATA = "metadata.yaml"


def is_bag(path: Path) -> bool:
    return (path.is_file() and path.suffix.lower() == BAG_SUFFIX) or (path / ROS2_METADATA).is_file()


def image_grey(msg, where: str) -> np.ndarray:
    """A deserialised ``sensor_msgs/Image`` as 2-D uint8 grey: ``data`` as ``height`` rows of ``step`` bytes."""
    encoding = str(msg.encoding).lower()
    if encoding not in ENCODINGS:
        raise DataError(f"{where}: image encoding {msg.encoding!r} is not read (only {', '.join(ENCODINGS)})")
    channels = 1 if ENCODINGS[encoding] is None else len(encoding) - 1
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if height < 1 or width < 1 or step < width * channels or data.size != height * step:
        raise DataError(
            f"{where}: a {width}x{height} {encoding} image with step {step} cannot hold {data.size} bytes of data"
        )
    pixels = data.reshape(height, step)[:, : width * channels].reshape(height, width, channels)
    code = ENCODINGS[encoding]
    if code is None:
        return pixels[:, :, 0].copy()
    import cv2

    return cv2.cvtColor(np.ascontiguousarray(pixels), getattr(cv2, code))


def bag_frames(path: str | Path, topic: str | None = None) -> Iterator[tuple[str, np.ndarray]]:
    """The frames of ``topic`` (or the bag's one image topic) in ``path``; the bag is opened and the topic
    chosen now, so a bad bag or topic fails before the first frame is asked for."""
    from rosbags.highlevel import AnyReader

    path = Path(path)
    reader = AnyReader([path])
    try:
        reader.open()
    except Exception as exc:  # rosbags raises its own reader errors, and OSError or KeyError on damaged files
        raise DataError(f"cannot read this bag ({type(exc).__name__}: {exc})".replace("\n", " "), path) from None
    images = sorted({c.topic for c in reader.connections if c.msgtype in (IMAGE, COMPRESSED)})
    chosen = topic if topic is not None else images[0] if len(images) == 1 else None
    if chosen not in images:
        reader.close()
        found = f"image topics {', '.join(images)}: give --topic" if images else "no image topic"
        problem = f"this bag holds {found} ({IMAGE} or {COMPRESSED})"
        if topic is not None:
            problem = f"no image topic {topic!r} in this bag (its image topics: {', '.join(images) or 'none'})"
        raise DataError(problem, path)
    return _messages(reader, path, str(chosen))


def _messages(reader, path: Path, topic: str) -> Iterator[tuple[str, np.ndarray]]:
    connections = [c for c in reader.connections if c.topic == topic]
    messages = reader.messages(connections=connections)
    try:
        for index in itertools.count():
            try:
                connection, _, raw = next(messages)
            except StopIteration:
                break
            except Exception as exc:  # a damaged or truncated bag
                raise DataError(f"message {index} of {topic} cannot be read ({type(exc).__name__})", path) from None
            if connection.msgtype == IMAGE:
                need = single_need(f"image message of {len(raw)} bytes, deserialised and converted", 2 * len(raw))
                check_memory(need, f"reading message {index} of {topic} in {path}", SMALLER)
            try:
                msg = reader.deserialize(raw, connection.msgtype)
            except Exception as exc:  # a message that does not deserialise
                raise DataError(f"message {index} of {topic} cannot be read ({type(exc).__name__})", path) from None
            where = f"{path}#{index}"
            if connection.msgtype == IMAGE:
                yield f"{path.name}#{index}", image_grey(msg, where)
            else:  # a CompressedImage, decoded like an image file
                yield f"{path.name}#{index}", decode_checked(bytes(msg.data), where, f"{msg.format!r} image")
        if index == 0:
            raise DataError(f"the topic {topic} holds no message", path)
        listed = sum(int(c.msgcount) for c in connections)
        if listed and index != listed:  # a damaged chunk can end the stream early without an error of its own
            raise DataError(
                f"the bag's index lists {listed} messages of {topic}, {index} could be read: a damaged chunk", path
            )
    finally:
        reader.close()
