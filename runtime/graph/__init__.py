"""The gravity-preserving submap graph (paper Sec. V.C): factors, robust loss and solver."""
from __future__ import annotations

from runtime.graph.config import GraphConfig
from runtime.graph.factors import GraphError, OdometryFactor, PointGroup, ScaleFactor
from runtime.graph.graph import NodeChange, NodeState, SolveReport, SubmapGraph
from runtime.graph.robust import huber_rho, huber_weight

__all__ = [
    "GraphConfig", "GraphError", "NodeChange", "NodeState", "OdometryFactor", "PointGroup", "ScaleFactor",
    "SolveReport", "SubmapGraph", "huber_rho", "huber_weight",
]
