"""AR.Drone 2.0 wire protocol: sans-I/O codecs (``at``, ``navdata``, ``video``) and the client
(``driver``: ``DriverProtocol`` core + ``ARDroneDriver`` asyncio). Errors in ``errors``."""
