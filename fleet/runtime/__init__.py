"""Running a fleet: worlds (the navigation backends plus time), the registry of backends by
name, the robot agents, the runner that owns the loop, and the run report."""
