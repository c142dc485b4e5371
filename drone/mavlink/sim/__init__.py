"""The simulated PX4-like autopilot, one module per MAVLink service."""
