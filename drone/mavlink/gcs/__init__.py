"""The ground-station side of a MAVLink link, one module per MAVLink microservice."""
