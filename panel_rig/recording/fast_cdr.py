"""Fixed-layout reads of the rig's high-rate messages from their CDR bytes: the tip
(``geometry_msgs/PointStamped``: z), the airspeed (``geometry_msgs/Vector3Stamped``: x), the modal states
(``sensor_msgs/JointState``: position) and a controller's command (``geometry_msgs/WrenchStamped``: force.z).
mcap-ros2's dynamic decoder builds a whole message object per sample, and
it took a third of `panel-rig analyze`'s time on a flutter test's bag (a million samples).

Each function returns None for bytes it does not read (not little-endian CDR): the caller decodes those the general
way. Offsets follow the CDR rules: the payload starts after the 4-byte encapsulation header, and a primitive is
aligned to its size relative to the payload's start."""

from __future__ import annotations

import struct

_U32 = struct.Struct("<I")
_F64 = struct.Struct("<d")
_PAYLOAD = 4  # the encapsulation header: representation id (2 bytes) and options (2 bytes)
_CDR_LE = b"\x00\x01"


def _align(pos: int, size: int) -> int:
    return pos + (-(pos - _PAYLOAD)) % size


def _after_header(data: bytes) -> int | None:
    """Offset just past the std_msgs/Header (stamp: int32 sec, uint32 nanosec; frame_id: uint32 length including
    its NUL, then the bytes); None unless little-endian CDR."""
    if data[:2] != _CDR_LE:
        return None
    return _PAYLOAD + 12 + _U32.unpack_from(data, _PAYLOAD + 8)[0]


def point_z(data: bytes) -> float | None:
    """PointStamped.point.z."""
    pos = _after_header(data)
    return None if pos is None else _F64.unpack_from(data, _align(pos, 8) + 16)[0]


def vector_x(data: bytes) -> float | None:
    """Vector3Stamped.vector.x."""
    pos = _after_header(data)
    return None if pos is None else _F64.unpack_from(data, _align(pos, 8))[0]


def wrench_force_z(data: bytes) -> float | None:
    """WrenchStamped.wrench.force.z (the force's x, y, z come first, as a point's)."""
    pos = _after_header(data)
    return None if pos is None else _F64.unpack_from(data, _align(pos, 8) + 16)[0]


def joint_positions(data: bytes) -> tuple[float, ...] | None:
    """JointState.position (after the names: a sequence of strings)."""
    pos = _after_header(data)
    if pos is None:
        return None
    pos = _align(pos, 4)
    n_names = _U32.unpack_from(data, pos)[0]
    pos += 4
    for _ in range(n_names):
        pos = _align(pos, 4)
        pos += 4 + _U32.unpack_from(data, pos)[0]
    pos = _align(pos, 4)
    n = _U32.unpack_from(data, pos)[0]
    return struct.unpack_from(f"<{n}d", data, _align(pos + 4, 8))
