"""Offered QoS profiles in the form rosbag2 (metadata version 9) records them."""

from __future__ import annotations

from typing import Any

import yaml

from panel_rig.recording.errors import RecordingError

# rmw reports "infinite"/default durations as INT64_MAX nanoseconds, split into sec/nsec.
_INFINITE = {"sec": 9223372036, "nsec": 854775807}


def _profile(history: str, depth: int, reliability: str, durability: str) -> dict[str, Any]:
    return {
        "history": history,
        "depth": depth,
        "reliability": reliability,
        "durability": durability,
        "deadline": dict(_INFINITE),
        "lifespan": dict(_INFINITE),
        "liveliness": "automatic",
        "liveliness_lease_duration": dict(_INFINITE),
        "avoid_ros_namespace_conventions": False,
    }


# "sensor" mirrors rclpy.qos.qos_profile_sensor_data; "reliable" is reliable/volatile/keep_last 10.
QOS_PROFILES: dict[str, dict[str, Any]] = {
    "sensor": _profile("keep_last", 5, "best_effort", "volatile"),
    "reliable": _profile("keep_last", 10, "reliable", "volatile"),
}


def offered_qos(name: str) -> list[dict[str, Any]]:
    """The offered QoS list for a named profile ("sensor" or "reliable")."""
    try:
        return [dict(QOS_PROFILES[name])]
    except KeyError:
        raise RecordingError(
            f"unknown qos {name!r}; expected one of {sorted(QOS_PROFILES)}"
        ) from None


def qos_yaml(profiles: list[dict[str, Any]]) -> str:
    """The YAML string rosbag2 stores in the MCAP channel metadata `offered_qos_profiles`."""
    return yaml.safe_dump(profiles, sort_keys=False, default_flow_style=False).rstrip("\n")
