"""The subsequence graph strategy (Tautges 2012, ch. 4): sparse, gappy optical markers
in, full-body motion out: its own options (`options`), the strategy and its live
session (`strategy`)."""

from graphsvc.strategies.ssg.options import SsgOptions
from graphsvc.strategies.ssg.strategy import STRATEGY, SsgSession, SsgStrategy

__all__ = ["STRATEGY", "SsgOptions", "SsgSession", "SsgStrategy"]
