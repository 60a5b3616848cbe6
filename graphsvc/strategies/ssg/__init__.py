"""The subsequence graph strategy (Tautges 2012, ch. 4): sparse, gappy optical markers
in, full-body motion out (`strategy`)."""

from graphsvc.strategies.ssg.strategy import SsgSession, SsgStrategy  # noqa: F401
