"""The multilinear strategy (Tautges 2012, ch. 2): per class of the knowledge base a
motion tensor of its units (steps of locomotion, whole clips of gestures) over styles
and repetitions, truncated by the HOSVD (`tensor`, `model`); a recording segmented and
classified by the Viterbi search, each unit's mode coefficients fitted so that its
simulated readings match the measured ones (`fit`); its own options (`options`), the
strategy (`strategy`)."""

from graphsvc.strategies.multilinear.options import MultilinearOptions
from graphsvc.strategies.multilinear.strategy import STRATEGY, MultilinearStrategy

__all__ = ["STRATEGY", "MultilinearOptions", "MultilinearStrategy"]
