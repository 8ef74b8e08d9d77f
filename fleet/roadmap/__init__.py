"""The warehouse roadmap: the graph robots drive on (:class:`Roadmap`), docks joining chargers
and parking spots to it, and readers of roadmap sources (SUMO ``.net.xml``)."""

from fleet.roadmap.graph import Roadmap

__all__ = ["Roadmap"]
