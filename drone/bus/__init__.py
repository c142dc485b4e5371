"""The fleet's bus (Zenoh): key space, payloads, credentials and the two sides that meet on it.

Sans-I/O parts: :mod:`keys`, :mod:`payloads`, :mod:`config` (JSON5-ready dicts, access control
built from the credentials). I/O parts: :mod:`session` (opens Zenoh), :mod:`console` (the
console's embedded router), :mod:`vehicle` (a vehicle's telemetry and liveliness).
Nothing here imports ``server``: a vehicle carries it without the web stack.
"""
