"""The baseline strategy: per sample the knowledge-base frame whose simulated readings
are nearest the measured ones (`strategy`), the floor a search must beat."""

from graphsvc.strategies.nearest.strategy import STRATEGY, NearestSession, NearestStrategy

__all__ = ["STRATEGY", "NearestSession", "NearestStrategy"]
