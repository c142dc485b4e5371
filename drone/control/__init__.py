"""Flight control: injected clocks, the paper's PID (eq. 1) and the 100 Hz control thread."""
