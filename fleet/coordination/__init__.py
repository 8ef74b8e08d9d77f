"""Coordination of the fleet: who does which task, robot health, and reassignment when a robot
drops out. The rules are in :mod:`fleet.coordination.coordinator`'s docstring.

* :mod:`~fleet.coordination.views`: the values (observations, robot views, orders, assignment
  and reassignment records, thresholds);
* :mod:`~fleet.coordination.tasks`: the :class:`~fleet.coordination.tasks.Task` protocol, its
  kinds (patrol routes, picks) and the task book;
* :mod:`~fleet.coordination.matching`: travel costs, the greedy matcher, charger allocation;
* :mod:`~fleet.coordination.health`: dead, stuck, charging, progress, blocked waypoints;
* :mod:`~fleet.coordination.policy`: the traffic-management extension point;
* :mod:`~fleet.coordination.state`: :class:`~fleet.coordination.state.CoordinatorState`,
  the decisions of one cycle, free of I/O;
* :mod:`~fleet.coordination.coordinator`: :class:`~fleet.coordination.coordinator.Coordinator`,
  which feeds the state from the bus and publishes its orders.
"""
