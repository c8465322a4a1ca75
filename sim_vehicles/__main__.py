"""`python -m sim_vehicles --mission FILE ...`"""

from sim_vehicles.cli import main

raise SystemExit(main())
