"""The command line, the swarm launcher and the flown-mission evaluation."""
