"""What the tests share: waiting on a condition (``polling``), loopback addresses and ports
(``loopback``), and a uvicorn server in a thread (``servers``)."""
