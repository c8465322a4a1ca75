"""`python -m sim_vehicles --mission FILE ...`"""

try:
    from sim_vehicles.cli import main
except KeyboardInterrupt:  # stopped while its modules load: quietly, as once they are loaded
    raise SystemExit(130) from None

raise SystemExit(main())
