"""The OLNG strategy's own options (Tautges et al. 2011; defaults from the paper), declared
once with `options.option()`: flags, checks, the gRPC form and the report's settings are
derived from them."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

from graphsvc.strategies.options import OptionError, option

WEIGHTS = ("w_prior", "w_contr", "w_pose", "w_motion", "w_smooth")
MAX_COUNT = 2**32 - 1  # (what the service's message holds; K is checked against the knowledge base where it is known)


@dataclass(frozen=True)
class OlngOptions:
    """k: neighbours a sample (None: the paper's share of the knowledge base, 4096 of
    about 600,000 frames, i.e. frames / 150, at least 16 and at most 4096); m: window
    columns; i: paths the pose is made from (None: the paper's K / 16, at least 4 and at
    most 256); extended: the extended steps (a column skipped, two to four frames on);
    w_prior, w_contr, w_pose, w_motion, w_smooth: the energy's weights (eq. 2–11);
    fix_feet: while the neighbourhood has a foot in contact, let it move only as the
    neighbours' feet moved (off by default: on Bandai dataset-2's takes 002, the tuning
    set, it cost 0.6 cm of mean joint error, 1.0 cm on gestures)."""

    k: int | None = option(
        None,
        low=1,
        high=MAX_COUNT,
        label="OLNG K",
        metavar="K",
        help="neighbours a sample (default: frames / 150, 16 to 4096, the paper's 4096 of ~600,000)",
    )
    m: int = option(32, low=2, high=MAX_COUNT, label="OLNG M", metavar="M", help="window columns (default 32)")
    i: int | None = option(
        None,
        low=1,
        high=MAX_COUNT,
        label="OLNG I",
        metavar="I",
        help="paths the pose is made from (default K / 16, 4 to 256)",
    )
    extended: bool = option(
        True,
        negated=("--olng-basic-steps",),
        label="OLNG extended steps",
        help="the extended steps, a column skipped (default on)",
    )
    w_prior: float = option(5.0, low=0.0, label="OLNG weight prior", help="energy weight of the prior (default 5)")
    w_contr: float = option(
        1.0, low=0.0, label="OLNG weight contr", help="energy weight of the control term (default 1)"
    )
    w_pose: float = option(0.6, low=0.0, label="OLNG weight pose", help="energy weight of the pose term (default 0.6)")
    w_motion: float = option(
        0.2, low=0.0, label="OLNG weight motion", help="energy weight of the motion term (default 0.2)"
    )
    w_smooth: float = option(
        0.2, low=0.0, label="OLNG weight smooth", help="energy weight of the smoothness term (default 0.2)"
    )
    fix_feet: bool = option(
        False,
        label="OLNG fix feet",
        help="foot clean-up: a foot in contact moves only as the neighbours' feet moved (costs accuracy; default off)",
    )

    # One flag for several fields: --olng-weights PRIOR,CONTR,POSE,MOTION,SMOOTH.
    flag_groups: ClassVar[dict] = {"weights": WEIGHTS}

    def check(self) -> None:
        if self.i is not None and self.k is not None and self.i > self.k:
            raise OptionError("i", f"OLNG I must be between 1 and K ({self.k}), got {self.i}")
        if self.w_prior * (self.w_pose + self.w_motion + self.w_smooth) + self.w_contr <= 0:
            raise OptionError("w_prior", "OLNG weights are all zero: the pose would be undetermined")

    def resolved(self, frames: int) -> OlngOptions:
        """K and I filled in for a knowledge base of `frames` frames."""
        k = self.k if self.k is not None else min(frames, 4096, max(16, round(frames / 150)))
        i = self.i if self.i is not None else min(k, 256, max(4, k // 16))
        return replace(self, k=k, i=i)
