"""Tools to test code built on the fleet, such as the navigation backend conformance checker."""
