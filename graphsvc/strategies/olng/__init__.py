"""The OLNG strategy (Tautges et al. 2011): per sample the knowledge-base frames with the
nearest readings, an online lazy neighbourhood graph over the last M samples' neighbours
(`lattice`), and, from its cheapest paths, an optimised pose (`pose`); its own options
(`options`), the strategy and its live session (`strategy`)."""

from graphsvc.strategies.olng.options import OlngOptions
from graphsvc.strategies.olng.strategy import STRATEGY, OlngSession, OlngStrategy

__all__ = ["STRATEGY", "OlngOptions", "OlngSession", "OlngStrategy"]
