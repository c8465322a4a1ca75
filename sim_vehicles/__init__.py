"""sim_vehicles: a fixed-wing kinematic simulator that speaks MAVLink like ArduPlane (or PX4).

One process hosts every vehicle of a mission, each on its own MAVLink 2 UDP endpoint, plus a
simulated downward camera publishing over Zenoh. See docs/simulator.md.
"""
