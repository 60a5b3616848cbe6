"""The piecewise strategy (Xie 2009): the knowledge base's poses reduced by PCA and
clustered with their readings by a Gaussian mixture, and per sample a pose from its
cluster's local model — an RBF map from readings to the reduced pose, or the
optimisation of a cluster prior, a control term and smoothness (`model`); its own
options (`options`), the strategy and its live session (`strategy`)."""

from graphsvc.strategies.piecewise.options import PiecewiseOptions
from graphsvc.strategies.piecewise.strategy import STRATEGY, PiecewiseSession, PiecewiseStrategy

__all__ = ["STRATEGY", "PiecewiseOptions", "PiecewiseSession", "PiecewiseStrategy"]
