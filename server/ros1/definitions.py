"""ROS 1 message definitions of the graph's types, in ``gendeps --cat`` form.

The graph's types (``server.msgs``) are written in ROS 2 shape (``builtin_interfaces/Time``
stamps, a ``std_msgs/Header`` without ``seq``). ROS 1 tools expect ROS 1 definitions: a time is
the primitive ``time`` (``uint32 secs, uint32 nsecs`` on the wire) and ``std_msgs/Header`` is
``uint32 seq, time stamp, string frame_id`` (ros/std_msgs ``msg/Header.msg``). This module maps
one onto the other, so the text rosapi ``topics_and_raw_types`` returns, the schema the
recorder writes and the bytes ``cbor-raw`` sends all agree.

The text format is what ``gendeps --cat`` and rosbag write (and ``@foxglove/rosmsg`` parses):
the type's own fields, then for each type it uses a line of 80 ``=``, ``MSG: pkg/Type`` and
that type's fields.
"""

from __future__ import annotations

from server import msgs
from server.ros1.errors import UnknownType

Field = tuple[str, str]

# ROS 2 time types are ROS 1 primitives.
TIME_TYPES = {"builtin_interfaces/Time": "time", "builtin_interfaces/Duration": "duration"}

# ROS 1 definitions that differ from the graph's ROS 2-shaped ones (ros/std_msgs Header.msg).
OVERRIDES: dict[str, tuple[Field, ...]] = {
    "std_msgs/Header": (("seq", "uint32"), ("stamp", "time"), ("frame_id", "string")),
}

# Constant lines of a type, written before its fields (ros/ros_comm rosgraph_msgs/Log.msg).
CONSTANTS: dict[str, tuple[str, ...]] = {
    "rosgraph_msgs/Log": (
        "byte DEBUG=1",
        "byte INFO=2",
        "byte WARN=4",
        "byte ERROR=8",
        "byte FATAL=16",
    ),
}

PRIMITIVES = frozenset(msgs.PRIMITIVES) | {"time", "duration"}
SEPARATOR = "=" * 80


def _map_type(field_type: str) -> str:
    base = msgs.base_type(field_type)
    suffix = field_type[len(base) :]
    return TIME_TYPES.get(base, base) + suffix


def ros1_fields(type_name: str) -> tuple[Field, ...]:
    """The ROS 1 fields of ``type_name`` (time types as primitives).

    Raises:
        UnknownType: no such type.
    """
    if type_name in OVERRIDES:
        return OVERRIDES[type_name]
    if type_name in TIME_TYPES or type_name not in msgs.MESSAGES:
        raise UnknownType(f"no ROS 1 definition for {type_name}")
    return tuple((name, _map_type(ftype)) for name, ftype in msgs.MESSAGES[type_name])


def dependencies(type_name: str) -> list[str]:
    """``type_name`` and every complex type it uses, depth first, each once.

    Raises:
        UnknownType: it, or a type it uses, has no definition.
    """
    order: list[str] = []

    def visit(name: str, path: str) -> None:
        if name in order:
            return
        try:
            fields = ros1_fields(name)
        except UnknownType:
            raise UnknownType(f"no ROS 1 definition for {name} (used by {path})") from None
        order.append(name)
        for fname, ftype in fields:
            base = msgs.base_type(ftype)
            if base not in PRIMITIVES:
                visit(base, f"{path}.{fname}")

    visit(type_name, type_name)
    return order


def has_definition(type_name: str) -> bool:
    """True when ``type_name`` and everything it uses have ROS 1 definitions."""
    try:
        dependencies(type_name)
    except UnknownType:
        return False
    return True


def _body(type_name: str) -> str:
    lines = list(CONSTANTS.get(type_name, ()))
    lines += [f"{ftype} {fname}" for fname, ftype in ros1_fields(type_name)]
    return "\n".join(lines)


def definition(type_name: str) -> str:
    """The full ``gendeps --cat`` definition of ``type_name``.

    Raises:
        UnknownType: it, or a type it uses, has no definition.
    """
    deps = dependencies(type_name)
    parts = [_body(deps[0])]
    parts += [f"{SEPARATOR}\nMSG: {dep}\n{_body(dep)}" for dep in deps[1:]]
    return "\n".join(parts)
