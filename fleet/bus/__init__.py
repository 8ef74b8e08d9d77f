"""The Zenoh bus of the fleet: sessions, key expressions, the status bus (statuses, tasks,
grants, liveliness) and the navigation protocol's server and client. Wire messages and their
codec live in :mod:`fleet.messages`, which imports no Zenoh."""
