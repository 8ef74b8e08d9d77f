"""Tools to test code built on the fleet: the navigation backend conformance checker
(:func:`fleet.testing.conformance.check_backend`) and the small known world it can run in
(:mod:`fleet.testing.room`). Imports only the core of the fleet (never pytest)."""
