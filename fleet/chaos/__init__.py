"""Chaos runs (``fleet chaos``): a fleet's processes killed with ``kill -9`` at random and
started again, judged by what the bus and the durable task book show (:mod:`fleet.chaos.run`)."""
