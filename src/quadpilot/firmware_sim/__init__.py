"""The simulator side of software-in-the-loop: plant, sensors, ESC behaviour, MAVLink server."""
