"""Message decoders for MCAP channels, keyed by (message encoding, schema encoding).

A decoder is built once per channel from its schema and turns one payload (``bytes``) into a
message object: a ``rosbags`` dataclass for ROS 1 and ROS 2 CDR channels, a protobuf message for
``protobuf`` channels and a ``dict`` for JSON channels. All schema work (parsing message
definitions, generating deserialisers, building protobuf descriptor pools) happens when the
decoder is built, never per message.

ROS type definitions are registered in a ``rosbags`` typestore of their own per distinct schema
(name and text), so two channels or two logs that carry different definitions under the same type
name never conflict; channels with identical schemas share one typestore and its compiled code.
"""

from __future__ import annotations

import json
import logging
import re
import struct
from collections.abc import Callable
from functools import lru_cache
from typing import TYPE_CHECKING, Any

from slamcli.errors import InputError
from slamcli.formats.mcap.records import ChannelInfo

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

log = logging.getLogger(__name__)

Decoder = Callable[[bytes], Any]
"""Turns one serialised message into a message object."""

DecoderFactory = Callable[[str, str, str, bytes], Decoder]
"""Builds a decoder from (topic, message encoding, schema name, schema data)."""

_IDL_SEPARATOR = re.compile(r"^={20,}[ \t]*\r?\n(?:IDL: [^\n]*\n)?", re.MULTILINE)
_IDL_DIRECTIVE = re.compile(r"^[ \t]*#[^\n]*$", re.MULTILINE)


class DecodeError(InputError):
    """A channel's messages cannot be decoded: unknown encoding, bad schema or bad payload."""


class _SchemaProblem(Exception):
    """Why a decoder cannot be built; turned into a :class:`DecodeError` naming the channel."""

    def __init__(self, reason: str, hint: str | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.hint = hint


def normalize_ros_type(name: str) -> str:
    """ROS 1 ``pkg/Type`` and ROS 2 ``pkg/msg/Type`` -> ``pkg/msg/Type``; other names unchanged."""
    parts = name.split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    return name


def _describe(topic: str, message_encoding: str, schema_encoding: str, schema_name: str) -> str:
    schema = f"schema {schema_name!r}" if schema_name else "no schema name"
    return (
        f"channel {topic}: {schema}, message encoding {message_encoding!r}, "
        f"schema encoding {schema_encoding!r}"
    )


def _schema_text(topic: str, schema_name: str, schema_data: bytes) -> str:
    try:
        return schema_data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _SchemaProblem(f"the schema is not UTF-8 text (byte {exc.start})") from None


@lru_cache(maxsize=256)
def _msg_typestore(schema_name: str, text: str) -> tuple[Typestore, str]:
    """A typestore holding the types of one ``.msg`` schema (main type plus ``MSG:`` blocks)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    typename = normalize_ros_type(schema_name)
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, typename))
    # Generating the (de)serialisers here surfaces missing dependency types before any message.
    store.get_msgdef(typename)
    return store, typename


@lru_cache(maxsize=256)
def _idl_typestore(schema_name: str, text: str) -> tuple[Typestore, str]:
    """A typestore holding the types of one ``ros2idl`` schema (``IDL:``-separated blocks)."""
    from rosbags.typesys import Stores, get_types_from_idl, get_typestore

    typename = normalize_ros_type(schema_name)
    types: dict[str, Any] = {}
    # rosbags' IDL grammar has no preprocessor; the files an #include names are the other
    # blocks of the same schema, so the directives can simply be dropped.
    for block in _IDL_SEPARATOR.split(_IDL_DIRECTIVE.sub("", text)):
        if block.strip():
            types.update(get_types_from_idl(block))
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    store.get_msgdef(typename)
    return store, typename


@lru_cache(maxsize=1)
def builtin_typestore() -> Typestore:
    """The ROS 2 Humble type definitions that ship with ``rosbags`` (for schema-less channels)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _build_store(
    schema_name: str,
    text: str,
    build: Callable[[str, str], tuple[Typestore, str]],
    kind: str,
) -> tuple[Typestore, str]:
    try:
        return build(schema_name, text)
    except Exception as exc:
        # rosbags' parsers and code generators raise a range of exception types on a bad or
        # incomplete definition; all of them mean the same thing to the user.
        raise _SchemaProblem(
            f"cannot parse the {kind} definition: {_one_line(exc)}",
            hint="the log's embedded message definition is malformed or incomplete",
        ) from exc


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    first = text[0] if text else ""
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def _payload_problem(exc: BaseException) -> str:
    """What a decoder's exception says about the payload, in the reader's terms.

    Deserialisers report a short or corrupt payload through whatever failed first (``struct``,
    slicing, UTF-8, allocation), often wrapped in their own error; the cause names the problem.
    """
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, struct.error | IndexError | EOFError | BufferError):
            return "it ends before all its fields are read (a length field is likely corrupt)"
        if isinstance(seen, UnicodeDecodeError):
            return f"a string field is not UTF-8 (byte {seen.start} of the string)"
        if isinstance(seen, MemoryError | OverflowError):
            return "a length or count field is implausibly large"
        if isinstance(seen, RecursionError):
            return "it nests too deeply"
        seen = seen.__cause__ or seen.__context__
    text = _one_line(exc)
    if "unpack" in text and "buffer" in text:
        return "it ends before all its fields are read (a length field is likely corrupt)"
    if "codec can't decode" in text:
        return "a string field is not UTF-8"
    return text


def _bad_payload(topic: str, what: str, data: bytes, exc: BaseException) -> DecodeError:
    return DecodeError(
        f"channel {topic}: a {what} message ({len(data)} bytes) does not decode: "
        f"{_payload_problem(exc)}"
    )


def _cdr_decoder(topic: str, store: Typestore, typename: str) -> Decoder:
    def decode(data: bytes) -> Any:
        try:
            return store.deserialize_cdr(data, typename)
        except Exception as exc:
            # A damaged payload can fail anywhere inside the generated deserialiser; whatever
            # it raises, the message is unreadable and the caller decides to skip or stop.
            raise _bad_payload(topic, f"{typename} CDR", data, exc) from exc

    return decode


def _cdr_from_msg(topic: str, encoding: str, schema_name: str, schema_data: bytes) -> Decoder:
    text = _schema_text(topic, schema_name, schema_data)
    store, typename = _build_store(schema_name, text, _msg_typestore, "ros2msg")
    return _cdr_decoder(topic, store, typename)


def _cdr_from_idl(topic: str, encoding: str, schema_name: str, schema_data: bytes) -> Decoder:
    text = _schema_text(topic, schema_name, schema_data)
    store, typename = _build_store(schema_name, text, _idl_typestore, "ros2idl")
    return _cdr_decoder(topic, store, typename)


def _cdr_builtin(topic: str, encoding: str, schema_name: str, schema_data: bytes) -> Decoder:
    store = builtin_typestore()
    typename = normalize_ros_type(schema_name)
    if typename not in store.fielddefs:
        raise _SchemaProblem(
            "the log has no definition for this type and it is not a standard ROS 2 Humble message",
            hint="re-record with the message package sourced so the definition is stored",
        )
    return _cdr_decoder(topic, store, typename)


def _ros1_from_msg(topic: str, encoding: str, schema_name: str, schema_data: bytes) -> Decoder:
    text = _schema_text(topic, schema_name, schema_data)
    store, typename = _build_store(schema_name, text, _msg_typestore, "ros1msg")

    def decode(data: bytes) -> Any:
        try:
            return store.deserialize_ros1(data, typename)
        except Exception as exc:
            raise _bad_payload(topic, f"{typename} ROS 1", data, exc) from exc

    return decode


@lru_cache(maxsize=256)
def _protobuf_class(schema_name: str, schema_data: bytes) -> Any:
    """The generated message class for ``schema_name`` in a serialised FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(schema_data)
    files = {f.name: f for f in fds.file}
    pool = descriptor_pool.DescriptorPool()
    added: set[str] = set()

    def add(name: str) -> None:
        # The pool needs every dependency before the file that imports it; writers store the
        # files in no particular order.
        if name in added:
            return
        added.add(name)
        proto = files[name]
        for dep in proto.dependency:
            if dep in files:
                add(dep)
        pool.Add(proto)

    for name in files:
        add(name)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def _protobuf(topic: str, encoding: str, schema_name: str, schema_data: bytes) -> Decoder:
    try:
        import google.protobuf  # noqa: F401
    except ImportError:
        raise _SchemaProblem(
            "decoding protobuf needs the 'protobuf' package",
            hint="pip install 'protobuf>=4.23'",
        ) from None
    if not schema_data:
        raise _SchemaProblem(
            "the protobuf schema data is empty (no FileDescriptorSet)",
            hint="the writer must embed the serialised FileDescriptorSet as the schema data",
        )
    try:
        cls = _protobuf_class(schema_name, bytes(schema_data))
    except Exception as exc:
        # Malformed descriptor sets fail inside protobuf with KeyError, TypeError or its own
        # errors depending on the backend (upb, C++ or pure Python).
        raise _SchemaProblem(
            f"cannot build the protobuf type from the schema's FileDescriptorSet: {_one_line(exc)}"
        ) from exc
    parse = cls.FromString

    def decode(data: bytes) -> Any:
        try:
            return parse(data)
        except Exception as exc:
            # protobuf's backends (upb, C++, pure Python) raise different types for bad wire
            # data; all mean the payload is unreadable.
            raise _bad_payload(topic, f"{schema_name} protobuf", data, exc) from exc

    return decode


def _json(topic: str, encoding: str, schema_name: str, schema_data: bytes) -> Decoder:
    what = schema_name or "JSON"

    def decode(data: bytes) -> Any:
        try:
            return json.loads(data)
        except (ValueError, RecursionError) as exc:
            raise _bad_payload(topic, f"{what} JSON", data, exc) from exc

    return decode


DECODERS: dict[tuple[str, str], DecoderFactory] = {
    ("cdr", "ros2msg"): _cdr_from_msg,
    ("cdr", "ros2idl"): _cdr_from_idl,
    ("cdr", ""): _cdr_builtin,
    ("ros1", "ros1msg"): _ros1_from_msg,
    ("protobuf", "protobuf"): _protobuf,
    ("json", "jsonschema"): _json,
    ("json", ""): _json,
}
"""Decoder factories keyed by (message encoding, schema encoding)."""


@lru_cache(maxsize=1024)
def _cached_decoder(
    topic: str, message_encoding: str, schema_encoding: str, schema_name: str, schema_data: bytes
) -> Decoder:
    factory = DECODERS.get((message_encoding, schema_encoding))
    if factory is None:
        known = ", ".join(f"{m}/{s or '(none)'}" for m, s in DECODERS)
        raise DecodeError(
            f"{_describe(topic, message_encoding, schema_encoding, schema_name)}: "
            "no decoder for this encoding pair",
            hint=f"decodable message/schema encodings: {known}",
        )
    try:
        decoder = factory(topic, message_encoding, schema_name, schema_data)
    except _SchemaProblem as exc:
        raise DecodeError(
            f"{_describe(topic, message_encoding, schema_encoding, schema_name)}: {exc.reason}",
            hint=exc.hint,
        ) from exc.__cause__
    log.debug("built decoder for %s (%s, %s)", topic, message_encoding, schema_name)
    return decoder


def decoder_for(channel: ChannelInfo) -> Decoder:
    """The decoder for a channel's messages, built on first use and cached.

    Raises:
        DecodeError: the encodings are unknown or the schema cannot be parsed; the message names
            the topic, the schema and the encodings.
    """
    return _cached_decoder(
        channel.topic,
        channel.message_encoding,
        channel.schema_encoding,
        channel.schema_name,
        bytes(channel.schema_data),
    )
