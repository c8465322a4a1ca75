"""`python -m sim_vehicles --mission FILE ...`"""

from companion.app.entry import interruptible

raise SystemExit(interruptible("sim_vehicles.cli"))
