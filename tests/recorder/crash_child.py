"""Records forever into DIR (argv[1]); after each flush prints how many messages are on disk.

Run by test_crash.py, which kills it with SIGKILL mid-flight.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from server import msgs
from server.graph import Graph
from server.recorder.recorder import Recorder, RecorderConfig

graph = Graph()
rec = Recorder(graph, RecorderConfig(Path(sys.argv[1]), chunk_s=0.0, chunk_size=4096))
rec.start(background=False)
n = 0
while True:
    for _ in range(40):
        msg = msgs.default_message("ardrone_autonomy/Navdata")
        msg["state"] = 3  # flying
        msg["tm"] = float(n)
        graph.publish("/ardrone/navdata", msg, type="ardrone_autonomy/Navdata")
        n += 1
    rec.step(time.time())  # chunk_s 0: every step finishes a chunk and hands it to the OS
    info = rec.current_info()
    print(f"flushed {info.messages if info else 0}", flush=True)
