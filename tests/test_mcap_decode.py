"""Message decoders: every encoding pair, the real ROS 2 log, and malformed schemas/payloads."""

from __future__ import annotations

import base64
import dataclasses
import json
from collections import Counter
from typing import Any

import numpy as np
import pytest
from conftest import shared_path

from slamcli.errors import InputError
from slamcli.formats.mcap.decode import DECODERS, DecodeError, decoder_for, normalize_ros_type
from slamcli.formats.mcap.records import ChannelInfo

_SEP = "=" * 80


def _humble() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _noetic() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC)


def _plain(obj: Any) -> Any:
    """A rosbags message as nested dicts/lists, so messages from two typestores compare."""
    if dataclasses.is_dataclass(obj):
        return {
            f.name: _plain(getattr(obj, f.name))
            for f in dataclasses.fields(obj)
            if f.name != "__msgtype__"
        }
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, list):
        return [_plain(x) for x in obj]
    return obj


def _channel(
    topic: str, msg_enc: str, schema_name: str, schema_enc: str, data: bytes | str = b""
) -> ChannelInfo:
    raw = data.encode() if isinstance(data, str) else data
    return ChannelInfo(1, topic, msg_enc, schema_name, schema_enc, raw)


def _pose_stamped(store: Any, sec: int = 12, nanosec: int = 345) -> Any:
    t = store.types
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="map"
    )
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=1.5, y=-2.0, z=0.25),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.6, w=0.8),
    )
    return t["geometry_msgs/msg/PoseStamped"](header=header, pose=pose)


def test_real_log_every_message_matches_reference_deserialisation() -> None:
    from mcap.reader import make_reader

    path = shared_path("mcap", "nav2_turtlebot.mcap")
    reference = _humble()
    counts: Counter[str] = Counter()
    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            assert schema is not None
            info = ChannelInfo.from_records(channel, schema)
            decoded = decoder_for(info)(message.data)
            # The reference uses rosbags' bundled Humble definitions, not the log's schema text.
            expected = reference.deserialize_cdr(message.data, schema.name)
            assert _plain(decoded) == _plain(expected)
            counts[channel.topic] += 1
    assert counts == {"/odom": 2639, "/tf": 5422, "/tf_static": 1, "/amcl_pose": 135}


def test_decoder_is_built_once_per_channel() -> None:
    store = _humble()
    text, _ = store.generate_msgdef("geometry_msgs/msg/PoseStamped", ros_version=2)
    ch = _channel("/pose", "cdr", "geometry_msgs/msg/PoseStamped", "ros2msg", text)
    assert decoder_for(ch) is decoder_for(dataclasses.replace(ch))


def test_ros2msg_round_trip() -> None:
    store = _humble()
    text, _ = store.generate_msgdef("geometry_msgs/msg/PoseStamped", ros_version=2)
    assert f"{_SEP}\nMSG: std_msgs/Header" in text
    ch = _channel("/pose", "cdr", "geometry_msgs/msg/PoseStamped", "ros2msg", text)
    msg = _pose_stamped(store)
    out = decoder_for(ch)(bytes(store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped")))
    assert _plain(out) == _plain(msg)
    assert out.header.stamp.nanosec == 345


def test_big_endian_cdr_payload() -> None:
    store = _humble()
    text, _ = store.generate_msgdef("geometry_msgs/msg/PoseStamped", ros_version=2)
    ch = _channel("/pose_be", "cdr", "geometry_msgs/msg/PoseStamped", "ros2msg", text)
    msg = _pose_stamped(store)
    raw = store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped", little_endian=False)
    assert bytes(raw[:2]) == b"\x00\x00"
    assert decoder_for(ch)(bytes(raw)).pose.position.x == 1.5


_IDL = {
    "builtin_interfaces/msg/Time": """
module builtin_interfaces {
  module msg {
    struct Time {
      int32 sec;
      uint32 nanosec;
    };
  };
};
""",
    "std_msgs/msg/Header": """// generated from rosidl_adapter/resource/msg.idl.em
// with input from std_msgs/msg/Header.msg
// generated code does not contain a copyright notice

#include "builtin_interfaces/msg/Time.idl"

module std_msgs {
  module msg {
    @verbatim (language="comment", text=
      "Standard metadata for higher-level stamped data types." "\n"
      "# in a particular coordinate frame.")
    struct Header {
      builtin_interfaces::msg::Time stamp;
      string frame_id;
    };
  };
};
""",
    "geometry_msgs/msg/Point": """
module geometry_msgs {
  module msg {
    struct Point {
      double x;
      double y;
      double z;
    };
  };
};
""",
    "geometry_msgs/msg/Quaternion": """
module geometry_msgs {
  module msg {
    struct Quaternion {
      @default (value=0.0)
      double x;
      @default (value=0.0)
      double y;
      @default (value=0.0)
      double z;
      @default (value=1.0)
      double w;
    };
  };
};
""",
    "geometry_msgs/msg/Pose": """
#include "geometry_msgs/msg/Point.idl"
#include "geometry_msgs/msg/Quaternion.idl"
module geometry_msgs {
  module msg {
    struct Pose {
      geometry_msgs::msg::Point position;
      geometry_msgs::msg::Quaternion orientation;
    };
  };
};
""",
}

_POSE_STAMPED_IDL = """
#include "std_msgs/msg/Header.idl"
#include "geometry_msgs/msg/Pose.idl"
module geometry_msgs {
  module msg {
    struct PoseStamped {
      std_msgs::msg::Header header;
      geometry_msgs::msg::Pose pose;
    };
  };
};
"""


def test_ros2idl_round_trip() -> None:
    store = _humble()
    text = _POSE_STAMPED_IDL + "".join(
        f"{_SEP}\nIDL: {name}\n{body}" for name, body in _IDL.items()
    )
    ch = _channel("/pose_idl", "cdr", "geometry_msgs/msg/PoseStamped", "ros2idl", text)
    msg = _pose_stamped(store, sec=7)
    out = decoder_for(ch)(bytes(store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped")))
    assert _plain(out) == _plain(msg)


def test_ros2idl_missing_dependency_raises() -> None:
    text = _POSE_STAMPED_IDL + f"{_SEP}\nIDL: std_msgs/msg/Header\n{_IDL['std_msgs/msg/Header']}"
    ch = _channel("/broken_idl", "cdr", "geometry_msgs/msg/PoseStamped", "ros2idl", text)
    with pytest.raises(DecodeError, match=r"/broken_idl.*ros2idl"):
        decoder_for(ch)


def test_empty_schema_uses_builtin_definition() -> None:
    store = _humble()
    t = store.types
    image = t["sensor_msgs/msg/Image"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=1, nanosec=2), frame_id="cam"
        ),
        height=2,
        width=3,
        encoding="mono8",
        is_bigendian=0,
        step=3,
        data=np.arange(6, dtype=np.uint8),
    )
    ch = _channel("/camera/image_raw", "cdr", "sensor_msgs/msg/Image", "")
    out = decoder_for(ch)(bytes(store.serialize_cdr(image, "sensor_msgs/msg/Image")))
    assert out.encoding == "mono8"
    assert out.data.tolist() == [0, 1, 2, 3, 4, 5]


def test_empty_schema_for_unknown_type_raises() -> None:
    ch = _channel("/custom", "cdr", "my_pkg/msg/Thing", "")
    with pytest.raises(DecodeError, match=r"/custom.*my_pkg/msg/Thing.*no definition") as err:
        decoder_for(ch)
    assert err.value.hint


def test_ros1_round_trip() -> None:
    noetic = _noetic()
    text, _ = noetic.generate_msgdef("geometry_msgs/msg/PoseStamped", ros_version=1)
    assert "uint32 seq" in text
    ch = _channel("/pose1", "ros1", "geometry_msgs/PoseStamped", "ros1msg", text)
    t = noetic.types
    msg = t["geometry_msgs/msg/PoseStamped"](
        header=t["std_msgs/msg/Header"](
            seq=4, stamp=t["builtin_interfaces/msg/Time"](sec=3, nanosec=9), frame_id="odom"
        ),
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=3.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )
    out = decoder_for(ch)(bytes(noetic.serialize_ros1(msg, "geometry_msgs/msg/PoseStamped")))
    assert _plain(out) == _plain(msg)
    assert out.header.seq == 4


def _file_descriptor_set(message_class: Any) -> bytes:
    """The schema data Foxglove writers embed: the message's file and all its imports."""
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    fds = FileDescriptorSet()
    seen: set[str] = set()

    def add(file: Any) -> None:
        if file.name in seen:
            return
        seen.add(file.name)
        for dep in file.dependencies:
            add(dep)
        file.CopyToProto(fds.file.add())

    add(message_class.DESCRIPTOR.file)
    return fds.SerializeToString()


def test_protobuf_round_trip_with_dependencies_in_any_order() -> None:
    pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    fds = FileDescriptorSet.FromString(_file_descriptor_set(FrameTransform))
    assert len(fds.file) > 2
    # The main file first, its imports after it: the decoder must order them itself.
    fds.file.reverse()
    assert fds.file[0].name.endswith("FrameTransform.proto")
    ch = _channel("/tf_fox", "protobuf", "foxglove.FrameTransform", "protobuf")
    ch = dataclasses.replace(ch, schema_data=fds.SerializeToString())
    msg = FrameTransform(parent_frame_id="world", child_frame_id="robot")
    msg.timestamp.seconds, msg.timestamp.nanos = 5, 6
    msg.translation.x = 2.5
    msg.rotation.w = 1.0
    out = decoder_for(ch)(msg.SerializeToString())
    assert out.parent_frame_id == "world"
    assert out.child_frame_id == "robot"
    assert (out.timestamp.seconds, out.timestamp.nanos) == (5, 6)
    assert out.translation.x == 2.5


def test_protobuf_bad_descriptor_set_raises() -> None:
    pytest.importorskip("google.protobuf")
    ch = _channel("/fox", "protobuf", "foxglove.RawImage", "protobuf", b"\xff\x00garbage")
    with pytest.raises(DecodeError, match=r"/fox.*foxglove.RawImage.*protobuf"):
        decoder_for(ch)


def test_protobuf_missing_message_type_raises() -> None:
    pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf.Pose_pb2 import Pose

    ch = _channel("/fox", "protobuf", "foxglove.RawImage", "protobuf", _file_descriptor_set(Pose))
    with pytest.raises(DecodeError, match=r"/fox.*foxglove.RawImage"):
        decoder_for(ch)


def test_protobuf_corrupt_payload_raises() -> None:
    pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf.Pose_pb2 import Pose

    ch = _channel("/pose_pb", "protobuf", "foxglove.Pose", "protobuf", _file_descriptor_set(Pose))
    with pytest.raises(DecodeError, match=r"/pose_pb.*foxglove.Pose"):
        decoder_for(ch)(b"\x0a\xff\xff\xff")


@pytest.mark.parametrize("schema_encoding", ["jsonschema", ""])
def test_json_decodes_to_dict(schema_encoding: str) -> None:
    payload = {"timestamp": {"sec": 1, "nsec": 2}, "data": base64.b64encode(b"\x01\x02").decode()}
    ch = _channel("/json", "json", "foxglove.CompressedImage", schema_encoding, "{}")
    out = decoder_for(ch)(json.dumps(payload).encode())
    assert out == payload


def test_json_garbage_raises() -> None:
    ch = _channel("/json_bad", "json", "foxglove.PoseInFrame", "jsonschema", "{}")
    with pytest.raises(DecodeError, match=r"/json_bad.*foxglove.PoseInFrame.*JSON"):
        decoder_for(ch)(b"{not json")


def test_unknown_encoding_pair_raises_naming_topic_and_encodings() -> None:
    ch = _channel("/weird", "flatbuffer", "foxglove.RawImage", "flatbuffer", b"\x00")
    with pytest.raises(DecodeError, match=r"/weird.*'flatbuffer'.*'flatbuffer'") as err:
        decoder_for(ch)
    assert isinstance(err.value, InputError)
    assert err.value.hint is not None and "cdr/ros2msg" in err.value.hint


def test_unparseable_ros2msg_schema_raises() -> None:
    ch = _channel("/bad_schema", "cdr", "my_pkg/msg/Bad", "ros2msg", "float64 x\n%%% nonsense\n")
    with pytest.raises(DecodeError, match=r"/bad_schema.*my_pkg/msg/Bad.*ros2msg.*parse"):
        decoder_for(ch)


def test_ros2msg_missing_dependency_raises() -> None:
    text = "std_msgs/Header header\nfloat64 x\n"
    ch = _channel("/no_deps", "cdr", "my_pkg/msg/Stamped", "ros2msg", text)
    with pytest.raises(DecodeError, match=r"/no_deps.*my_pkg/msg/Stamped"):
        decoder_for(ch)


def test_non_utf8_schema_raises() -> None:
    ch = _channel("/latin", "cdr", "my_pkg/msg/X", "ros2msg", b"float64 \xff\n")
    with pytest.raises(DecodeError, match=r"/latin.*not UTF-8"):
        decoder_for(ch)


def test_corrupt_cdr_payload_raises() -> None:
    store = _humble()
    text, _ = store.generate_msgdef("geometry_msgs/msg/PoseStamped", ros_version=2)
    ch = _channel("/pose_cut", "cdr", "geometry_msgs/msg/PoseStamped", "ros2msg", text)
    raw = bytes(store.serialize_cdr(_pose_stamped(store), "geometry_msgs/msg/PoseStamped"))
    with pytest.raises(DecodeError, match=r"/pose_cut.*PoseStamped"):
        decoder_for(ch)(raw[:20])
    with pytest.raises(DecodeError, match=r"/pose_cut"):
        decoder_for(ch)(b"\x07\x07" + raw[2:])


def test_registry_covers_the_documented_pairs() -> None:
    assert set(DECODERS) == {
        ("cdr", "ros2msg"),
        ("cdr", "ros2idl"),
        ("cdr", ""),
        ("ros1", "ros1msg"),
        ("protobuf", "protobuf"),
        ("json", "jsonschema"),
        ("json", ""),
    }


def test_normalize_ros_type() -> None:
    assert normalize_ros_type("sensor_msgs/Image") == "sensor_msgs/msg/Image"
    assert normalize_ros_type("sensor_msgs/msg/Image") == "sensor_msgs/msg/Image"
    assert normalize_ros_type("foxglove.RawImage") == "foxglove.RawImage"
