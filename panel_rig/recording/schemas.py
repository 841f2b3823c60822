"""ROS 2 message definitions as rosbag2 stores them: `ros2msg` schema text and RIHS01 type hashes.

The `.msg`/`.json` files come from the installed interface packages (`<prefix>/share/<pkg>/msg/`),
found next to the running interpreter first and then through the ament index.
"""

from __future__ import annotations

import functools
import json
import re
import sys
from pathlib import Path
from typing import Any

from panel_rig.recording.errors import RecordingError

SCHEMA_ENCODING = "ros2msg"
SEPARATOR = "=" * 80
PRIMITIVE_TYPES = frozenset(
    {
        "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
        "int32", "uint32", "int64", "uint64", "string", "wstring",
    }
)
_ARRAY_SUFFIX = re.compile(r"\[[^\]]*\]$")
_BOUND_SUFFIX = re.compile(r"<=\d+$")


def type_name_of(msg: Any) -> str:
    """Full ROS type name (`pkg/msg/Type`) of an rclpy message instance or class."""
    cls = msg if isinstance(msg, type) else type(msg)
    module = getattr(cls, "__module__", "")
    pkg, _, sub = module.partition(".")
    if not hasattr(cls, "get_fields_and_field_types") or not sub.startswith("msg"):
        raise RecordingError(f"not an rclpy message: {cls.__module__}.{cls.__name__}")
    return f"{pkg}/msg/{cls.__name__}"


def split_type_name(type_name: str) -> tuple[str, str]:
    """`pkg/msg/Type` or `pkg/Type` -> (`pkg`, `Type`)."""
    parts = type_name.split("/")
    if len(parts) not in (2, 3) or not all(parts):
        raise RecordingError(f"bad ROS type name {type_name!r}")
    return parts[0], parts[-1]


@functools.cache
def _share_dir(pkg: str) -> Path:
    candidate = Path(sys.prefix) / "share" / pkg
    if candidate.is_dir():
        return candidate
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(pkg))
    except Exception as exc:  # noqa: BLE001 - any lookup failure is the same for the caller
        raise RecordingError(f"interface package {pkg!r} not found ({exc})") from None


def _interface_file(type_name: str, suffix: str) -> Path:
    pkg, name = split_type_name(type_name)
    path = _share_dir(pkg) / "msg" / f"{name}{suffix}"
    if not path.is_file():
        raise RecordingError(f"no {suffix} file for {type_name} (looked at {path})")
    return path


@functools.cache
def msg_text(type_name: str) -> str:
    """The type's own `.msg` text, as installed."""
    return _interface_file(type_name, ".msg").read_text(encoding="utf-8")


def _field_type(line: str) -> str | None:
    """Base type of a field line (None for comments, blanks and constants)."""
    code = line.split("#", 1)[0].strip()
    if not code:
        return None
    parts = code.split(None, 1)
    if len(parts) < 2 or "=" in parts[1].split(None, 1)[0]:
        return None  # constant: `TYPE NAME=value`
    base = _BOUND_SUFFIX.sub("", _ARRAY_SUFFIX.sub("", parts[0]))
    return base


def dependencies(type_name: str) -> list[str]:
    """Direct non-primitive dependencies (`pkg/Type`), in field order, without duplicates."""
    pkg, _ = split_type_name(type_name)
    deps: list[str] = []
    for line in msg_text(type_name).splitlines():
        base = _field_type(line)
        if base is None or base in PRIMITIVE_TYPES:
            continue
        dep = base if "/" in base else f"{pkg}/{base}"
        dep_pkg, dep_name = split_type_name(dep)
        dep = f"{dep_pkg}/{dep_name}"
        if dep not in deps:
            deps.append(dep)
    return deps


@functools.cache
def schema_text(type_name: str) -> str:
    """rosbag2's concatenated definition: own text, then each dependency depth-first, once."""
    pieces = [msg_text(type_name)]
    seen: set[str] = set()

    def visit(name: str) -> None:
        for dep in dependencies(name):
            if dep in seen:
                continue
            seen.add(dep)
            text = msg_text(dep)
            pieces.append(f"{SEPARATOR}\nMSG: {dep}\n{text}")
            visit(dep)

    visit(type_name)
    joined = ""
    for piece in pieces:
        if joined and not joined.endswith("\n"):
            joined += "\n"
        joined += piece
    return joined


@functools.cache
def type_hash(type_name: str) -> str:
    """RIHS01 type description hash from the package's generated `.json`."""
    pkg, name = split_type_name(type_name)
    full = f"{pkg}/msg/{name}"
    try:
        data = json.loads(_interface_file(full, ".json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RecordingError(f"cannot read type hash of {full}: {exc}") from None
    for entry in data.get("type_hashes", []):
        if entry.get("type_name") == full:
            return str(entry["hash_string"])
    raise RecordingError(f"no type hash for {full} in its .json")
