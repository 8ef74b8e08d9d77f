"""Coordination of the fleet: who does which task, robot health, and reassignment when a robot
drops out. :class:`~fleet.coordination.coordinator.CoordinatorState` decides free of I/O;
:class:`~fleet.coordination.coordinator.Coordinator` feeds it from the bus."""
