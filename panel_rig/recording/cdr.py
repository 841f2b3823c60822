"""CDR payload normalisation so that strict readers (`rosbags`) accept every recorded message.

rclpy/Fast-CDR returns a buffer longer than the encoded data when the message *ends* in an empty
sequence (it reserves alignment for elements that never come, and the extra bytes are not even
zeroed). Lenient readers (mcap-ros2, rosbag2) ignore the tail; `rosbags` refuses any tail longer
than 3 bytes. When the last leaf field of a message is an empty sequence, we decode the payload
once with mcap-ros2's CDR reader to find where the data really ends and cut the tail there
(rounded up to 4 bytes, as CDR pads). The decoded content is unchanged for every reader. Other
messages are written byte for byte as rclpy serialised them (no extra cost).
"""

from __future__ import annotations

import functools
from typing import Any

_SEQUENCE_TYPES = (list, tuple)


def _is_sequence_value(value: Any) -> bool:
    if isinstance(value, (str, bytes)):
        return False
    return isinstance(value, _SEQUENCE_TYPES) or hasattr(value, "__len__") and hasattr(
        value, "__getitem__"
    )


def ends_with_empty_sequence(msg: Any) -> bool:
    """True if the last leaf field of an rclpy message (recursively) is an empty sequence."""
    fields = getattr(msg, "get_fields_and_field_types", None)
    if fields is None:
        return False
    names = list(fields())
    if not names:
        return False
    value = getattr(msg, names[-1])
    if hasattr(value, "get_fields_and_field_types"):
        return ends_with_empty_sequence(value)
    if _is_sequence_value(value):
        if len(value) == 0:
            return True
        last = value[-1]
        return hasattr(last, "get_fields_and_field_types") and ends_with_empty_sequence(last)
    return False


@functools.lru_cache(maxsize=64)
def _msgdefs(type_name: str, schema: str) -> dict[str, Any]:
    from mcap_ros2._dynamic import (  # private, guarded by caller
        TimeDefinition,
        _for_each_msgdef,
    )

    defs: dict[str, Any] = {
        "builtin_interfaces/Time": TimeDefinition,
        "builtin_interfaces/Duration": TimeDefinition,
    }

    def add(name: str, short: str, msgdef: Any) -> None:
        defs[name] = msgdef
        defs[short] = msgdef

    _for_each_msgdef(type_name, schema, add)
    return defs


def encoded_length(type_name: str, schema: str, data: bytes) -> int:
    """Bytes the CDR payload really uses (header included), rounded up to 4."""
    from mcap_ros2._cdr import CdrReader
    from mcap_ros2._dynamic import _read_complex_type

    defs = _msgdefs(type_name, schema)
    reader = CdrReader(data)
    _read_complex_type(defs[type_name], defs, reader, {})
    used = reader.decoded_bytes()
    return min(len(data), (used + 3) // 4 * 4)


def trim_trailing_padding(type_name: str, schema: str, msg: Any, data: bytes) -> bytes:
    """Cut the unused tail of a payload that ends in an empty sequence; else return `data`.

    Falls back to the untouched payload if the decoder is unavailable or fails.
    """
    if not ends_with_empty_sequence(msg):
        return data
    try:
        return data[: encoded_length(type_name, schema, data)]
    except Exception:  # noqa: BLE001 - never lose a message over a cosmetic trim
        return data
