"""Flight recorder: every graph topic of every drone to MCAP, the flight index, replay.

- :mod:`server.recorder.channels`: the MCAP schema and encoding of a graph type (``ros1msg``
  with the full ROS 1 definition; JSON Schema + JSON for a type with no definition).
- :mod:`server.recorder.mcapfile`: writing one flight file, and reading one back tolerantly
  (a file cut short by a crash reads up to its last finished chunk).
- :mod:`server.recorder.sessions`: where a flight session starts and ends (sans-I/O).
- :mod:`server.recorder.index`: the recordings directory: list, delete, disk budget, repair.
- :mod:`server.recorder.recorder`: the graph tap and the writer thread.
- :mod:`server.recorder.replay`: a recording played back onto a graph, with a timeline.
- :mod:`server.recorder.replay_app` / :mod:`server.recorder.replay_cli`: ``uav-console replay``,
  the console served read-only on a recording.

Elsewhere: ``server.ros1`` (ROS 1 definitions and serialisation), ``server.rosbridge.cborraw``
(``compression: "cbor-raw"``), ``server.nodes.rosout`` (``/rosout``), ``server.api.flights`` (REST).
"""
