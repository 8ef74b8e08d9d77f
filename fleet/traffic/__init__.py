"""Traffic management on the roadmap (``docs/traffic.md``): reservations of nodes and edges, the
manager that grants each robot the part of its path it may drive, deadlock resolution, the
coordinator's policy, and the robot-side follower of grants."""
