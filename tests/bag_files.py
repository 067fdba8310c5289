"""ROS 1 bags and ROS 2 bag folders written from an MCAP log's messages with ``rosbags``, for
the tests that read bags."""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import Any


def mcap_messages(path: Path) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, schema name, log time, data) of each message of an MCAP log."""
    from mcap.reader import make_reader

    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            assert schema is not None
            yield channel.topic, schema.name, message.log_time, message.data


def ros2_bag(mcap: Path, out: Path, storage: str, compress: bool = False) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(out, version=Writer.VERSION_LATEST, storage_plugin=plugin)
    if compress:
        writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        conns: dict[str, Any] = {}
        for topic, schema, stamp, data in mcap_messages(mcap):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, schema, typestore=store)
            writer.write(conns[topic], stamp, data)
    return out


def _to_ros1(msg: Any, store: Any) -> Any:
    """A ROS 2 message as the ROS 1 (Noetic) message of the same type: the same fields (ROS 1
    spells CameraInfo's in upper case) and a zero header ``seq``."""
    if isinstance(msg, list | tuple):
        return [_to_ros1(m, store) for m in msg]
    if not dataclasses.is_dataclass(msg):
        return msg
    cls = store.types[msg.__msgtype__]
    values = {}
    for f in dataclasses.fields(cls):
        if f.name == "__msgtype__":
            continue
        name = f.name if hasattr(msg, f.name) else f.name.lower()
        values[f.name] = _to_ros1(getattr(msg, name), store) if hasattr(msg, name) else 0
    return cls(**values)


def ros1_bag(
    mcap: Path,
    out: Path,
    compression: str = "none",
    chunk: int = 1 << 20,
    topics: Collection[str] | None = None,
) -> Path:
    """A ROS 1 bag of an MCAP log's ROS 2 messages (only ``topics``, when given), as a
    ROS 1 recorder would have written them."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ros2 = get_typestore(Stores.ROS2_HUMBLE)
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    if "tf2_msgs/msg/TFMessage" not in ros1.types:
        # Noetic's store lacks tf2_msgs; /tf and /tf_static are TFMessage in ROS 1 too.
        from rosbags.typesys import get_types_from_msg

        ros1.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
        )
    writer = Writer(out)
    writer.chunk_threshold = chunk
    if compression != "none":
        writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    with writer:
        conns: dict[str, Any] = {}
        for topic, schema, stamp, data in mcap_messages(mcap):
            if topics is not None and topic not in topics:
                continue
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, schema, typestore=ros1)
            msg = _to_ros1(ros2.deserialize_cdr(data, schema), ros1)
            writer.write(conns[topic], stamp, ros1.serialize_ros1(msg, schema))
    return out
