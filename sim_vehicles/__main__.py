"""`python -m sim_vehicles --mission FILE ...`"""

from companion.contracts.entry import interruptible

raise SystemExit(interruptible("sim_vehicles.cli"))
