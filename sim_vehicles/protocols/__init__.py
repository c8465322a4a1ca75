"""MAVLink microservices of a simulated vehicle: commands, parameters, missions, MAVFTP."""
