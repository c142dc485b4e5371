"""rosapi introspection services on the graph, with rosapi's request/response field names.

Names are registered canonically (``/rosapi/topics``); the graph maps ``rosapi/topics`` (as
roslibjs spells it) to the same service. Response shapes follow rosapi (rosbridge_suite
``rosapi/srv/*.srv``) as roslibjs and roslibpy read them: parameters travel as JSON text
(``get_param`` -> ``value``; ``set_param`` takes ``value: JSON.stringify(v)``), ``get_time``
returns ``{sec, nanosec}`` and also ROS 1's ``{secs, nsecs}`` (roslibpy reads the latter).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Awaitable, Callable
from typing import Any

from server import msgs
from server.graph import Graph, canonical
from server.ros1 import definition as ros1_definition
from server.ros1 import has_definition
from server.rosbridge.values import normalise_type

Handler = Callable[[dict[str, Any]], Awaitable[dict[str, Any]]]

# service type -> request fields in order (for call_service with list args)
REQUEST_FIELDS: dict[str, tuple[str, ...]] = {
    "rosapi/Topics": (),
    "rosapi/TopicsForType": ("type",),
    "rosapi/TopicType": ("topic",),
    "rosapi/Services": (),
    "rosapi/ServicesForType": ("type",),
    "rosapi/ServiceType": ("service",),
    "rosapi/ServiceNode": ("service",),
    "rosapi/ServiceProviders": ("service",),
    "rosapi/Nodes": (),
    "rosapi/NodeDetails": ("node",),
    "rosapi/Publishers": ("topic",),
    "rosapi/Subscribers": ("topic",),
    "rosapi/GetParam": ("name", "default"),
    "rosapi/SetParam": ("name", "value"),
    "rosapi/DeleteParam": ("name",),
    "rosapi/HasParam": ("name",),
    "rosapi/GetParamNames": (),
    "rosapi/GetTime": (),
    "rosapi/MessageDetails": ("type",),
    "rosapi/ServiceRequestDetails": ("type",),
    "rosapi/ServiceResponseDetails": ("type",),
    "rosapi/GetActionServers": (),
    "rosapi/TopicsAndRawTypes": (),
}


def _str_arg(args: dict[str, Any], name: str) -> str:
    value = args.get(name, "")
    if not isinstance(value, str):
        raise ValueError(f"'{name}' must be a string")
    return value


def typedefs(type_name: str) -> list[dict[str, Any]]:
    """rosapi ``message_details`` typedefs of ``type_name`` and every type it contains."""
    out: list[dict[str, Any]] = []
    seen: set[str] = set()

    def visit(name: str) -> None:
        if name in seen or name not in msgs.MESSAGES:
            return
        seen.add(name)
        fields = msgs.MESSAGES[name]
        example = msgs.default_message(name)
        out.append(
            {
                "type": name,
                "fieldnames": [f for f, _ in fields],
                "fieldtypes": [msgs.base_type(t) for _, t in fields],
                # rosapi objectutils: -1 scalar, 0 variable-length array
                "fieldarraylen": [msgs.array_length(t) for _, t in fields],
                "examples": [
                    "{}"
                    if msgs.base_type(t) in msgs.MESSAGES and not msgs.is_array(t)
                    else json.dumps(example.get(f))
                    for f, t in fields
                ],
                "constnames": [],
                "constvalues": [],
            }
        )
        for _, t in fields:
            visit(msgs.base_type(t))

    visit(type_name)
    return out


def full_text(type_name: str) -> str:
    """The ``gendeps --cat`` style definition of a type (rosapi ``topics_and_raw_types``).

    ROS 1 definitions (``server.ros1``: ``time`` stamps, ``Header`` with ``seq``), which is what
    ``cbor-raw`` serialises and the recorder writes; "" for a type with no definition.
    """
    if has_definition(type_name):
        return ros1_definition(type_name)
    return _typedefs_full_text(type_name)


def _typedefs_full_text(type_name: str) -> str:
    parts: list[str] = []
    for td in typedefs(type_name):
        lines = [
            f"{t}{'[]' if n == 0 else f'[{n}]' if n > 0 else ''} {f}"
            for f, t, n in zip(td["fieldnames"], td["fieldtypes"], td["fieldarraylen"], strict=True)
        ]
        head = "" if td["type"] == type_name else "=" * 80 + f"\nMSG: {td['type']}\n"
        parts.append(head + "\n".join(lines))
    return "\n".join(parts)


def register_rosapi(  # noqa: C901
    graph: Graph,
    *,
    wall_clock: Callable[[], float] = time.time,
    request_fields: dict[str, tuple[str, ...]] | None = None,
) -> list[str]:
    """Provide the rosapi services on ``graph``; returns their canonical names.

    Complexity: each service is a small closure over ``graph`` defined here, and the
    measure counts them all as this function's branches."""
    if request_fields is not None:
        request_fields.update(REQUEST_FIELDS)

    def nodes() -> list[str]:
        return list(graph.owners())

    async def topics(args: dict[str, Any]) -> dict[str, Any]:
        t = graph.topics()
        return {"topics": list(t), "types": list(t.values())}

    async def topics_for_type(args: dict[str, Any]) -> dict[str, Any]:
        want = normalise_type(_str_arg(args, "type"))
        return {"topics": [n for n, t in graph.topics().items() if t == want]}

    async def topic_type(args: dict[str, Any]) -> dict[str, Any]:
        return {"type": graph.topic_type(_str_arg(args, "topic") or "/") or ""}

    async def services(args: dict[str, Any]) -> dict[str, Any]:
        s = graph.services()
        return {"services": list(s), "types": list(s.values())}

    async def services_for_type(args: dict[str, Any]) -> dict[str, Any]:
        want = _str_arg(args, "type")
        return {"services": [n for n, t in graph.services().items() if t == want]}

    async def service_type(args: dict[str, Any]) -> dict[str, Any]:
        return {"type": graph.service_type(_str_arg(args, "service") or "/") or ""}

    async def service_node(args: dict[str, Any]) -> dict[str, Any]:
        return {"node": graph.service_owner(_str_arg(args, "service") or "/") or ""}

    async def service_providers(args: dict[str, Any]) -> dict[str, Any]:
        owner = graph.service_owner(_str_arg(args, "service") or "/")
        return {"providers": [owner] if owner else []}

    async def nodes_srv(args: dict[str, Any]) -> dict[str, Any]:
        return {"nodes": nodes()}

    async def node_details(args: dict[str, Any]) -> dict[str, Any]:
        node = _str_arg(args, "node")
        return {
            "subscribing": [t for t in graph.topics() if node in graph.subscribers(t)],
            "publishing": [t for t in graph.topics() if node in graph.publishers(t)],
            "services": [s for s in graph.services() if graph.service_owner(s) == node],
        }

    async def publishers(args: dict[str, Any]) -> dict[str, Any]:
        return {"publishers": graph.publishers(_str_arg(args, "topic") or "/")}

    async def subscribers(args: dict[str, Any]) -> dict[str, Any]:
        return {"subscribers": graph.subscribers(_str_arg(args, "topic") or "/")}

    async def get_param(args: dict[str, Any]) -> dict[str, Any]:
        name = _str_arg(args, "name")
        if graph.has_param(name):
            return {"value": json.dumps(graph.get_param(name)), "successful": True, "reason": ""}
        default = args.get("default") or "null"
        return {"value": default, "successful": True, "reason": ""}

    async def set_param(args: dict[str, Any]) -> dict[str, Any]:
        name = _str_arg(args, "name")
        raw = args.get("value", "null")
        try:
            value = json.loads(raw) if isinstance(raw, str) else raw
            graph.set_param(name, value)
        except (ValueError, TypeError) as exc:
            return {"successful": False, "reason": f"value must be JSON text: {exc}"}
        return {"successful": True, "reason": ""}

    async def delete_param(args: dict[str, Any]) -> dict[str, Any]:
        name = _str_arg(args, "name")
        if not graph.has_param(name):
            return {"successful": False, "reason": f"parameter {canonical(name)} is not set"}
        graph.delete_param(name)
        return {"successful": True, "reason": ""}

    async def has_param(args: dict[str, Any]) -> dict[str, Any]:
        return {"exists": graph.has_param(_str_arg(args, "name"))}

    async def get_param_names(args: dict[str, Any]) -> dict[str, Any]:
        return {"names": graph.param_names()}

    async def get_time(args: dict[str, Any]) -> dict[str, Any]:
        t = wall_clock()
        sec = math.floor(t)
        nsec = int((t - sec) * 1e9) % 1_000_000_000
        return {"time": {"sec": int(sec), "nanosec": nsec, "secs": int(sec), "nsecs": nsec}}

    async def message_details(args: dict[str, Any]) -> dict[str, Any]:
        name = normalise_type(_str_arg(args, "type"))
        if name not in msgs.MESSAGES:
            raise ValueError(f"unknown message type {name}")
        return {"typedefs": typedefs(name)}

    async def no_typedefs(args: dict[str, Any]) -> dict[str, Any]:
        return {"typedefs": []}  # service types are not described by server.msgs

    async def action_servers(args: dict[str, Any]) -> dict[str, Any]:
        return {"action_servers": []}

    async def topics_and_raw_types(args: dict[str, Any]) -> dict[str, Any]:
        t = graph.topics()
        return {
            "topics": list(t),
            "types": list(t.values()),
            "typedefs_full_text": [full_text(v) for v in t.values()],
        }

    table: dict[str, tuple[str, Handler]] = {
        "topics": ("rosapi/Topics", topics),
        "topics_for_type": ("rosapi/TopicsForType", topics_for_type),
        "topic_type": ("rosapi/TopicType", topic_type),
        "services": ("rosapi/Services", services),
        "services_for_type": ("rosapi/ServicesForType", services_for_type),
        "service_type": ("rosapi/ServiceType", service_type),
        "service_node": ("rosapi/ServiceNode", service_node),
        "service_providers": ("rosapi/ServiceProviders", service_providers),
        "nodes": ("rosapi/Nodes", nodes_srv),
        "node_details": ("rosapi/NodeDetails", node_details),
        "publishers": ("rosapi/Publishers", publishers),
        "subscribers": ("rosapi/Subscribers", subscribers),
        "get_param": ("rosapi/GetParam", get_param),
        "set_param": ("rosapi/SetParam", set_param),
        "delete_param": ("rosapi/DeleteParam", delete_param),
        "has_param": ("rosapi/HasParam", has_param),
        "get_param_names": ("rosapi/GetParamNames", get_param_names),
        "get_time": ("rosapi/GetTime", get_time),
        "message_details": ("rosapi/MessageDetails", message_details),
        "service_request_details": ("rosapi/ServiceRequestDetails", no_typedefs),
        "service_response_details": ("rosapi/ServiceResponseDetails", no_typedefs),
        "action_servers": ("rosapi/GetActionServers", action_servers),
        "topics_and_raw_types": ("rosapi/TopicsAndRawTypes", topics_and_raw_types),
    }
    return [graph.advertise_service(f"/rosapi/{n}", t, h) for n, (t, h) in table.items()]
