"""Track networks (docs/network.md): sections joined at switches and crossings, paths through
them, and the track-selective fusion that keeps a hypothesis per feasible path.

  model.py    sections, nodes (point_switch, crossing, link), the YAML form and its checks
  path.py     paths through the network: the path distance, routes and their route lines
"""
from .model import Continuation, Network, NetworkError, Node, SectionEnd, is_network
from .path import PathStep, TrackPath, route_path, route_track

__all__ = ["Continuation", "Network", "NetworkError", "Node", "SectionEnd", "is_network", "PathStep", "TrackPath",
           "route_path", "route_track"]
