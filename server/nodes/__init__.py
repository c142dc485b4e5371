"""Graph nodes: a drone on the graph (the AR.Drone topics, MAVROS for MAVLink) and rosout."""
