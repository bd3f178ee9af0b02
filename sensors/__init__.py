"""sensors: scanner models as data, scan patterns, trajectories, return physics (to come)."""
