"""One UAV's process: the MAVLink link to its vehicle, the Zenoh mesh, the camera feed, frames."""
