"""The multilinear strategy's own options (`--multilinear-<field>`)."""

from __future__ import annotations

from dataclasses import dataclass

from graphsvc.strategies.options import option


@dataclass(frozen=True)
class MultilinearOptions:
    """variance: the share of each natural mode's (style, repetition) variance its
    truncation keeps; align: how units are put on their reference's frames (linear,
    dtw, or auto: steps linear, whole clips dtw); max_reps: the most units a style gives a step tensor; label: the
    class of the whole recording (None: each stretch's from the Viterbi search);
    prior: the weight pulling a unit's coefficients toward its starting row's;
    warp: optimise each unit's time warp too; hold_feet: hold the feet the units
    plant (`synthesis.foot_hold`); evaluations: the most residual
    evaluations a unit's least squares may make."""

    variance: float = option(
        0.99,
        low=0.0,
        high=1.0,
        low_open=True,
        label="multilinear variance",
        noun="a share above 0 and at most 1",
        help="share of each natural mode's variance its truncation keeps (default 0.99)",
    )
    align: str = option(
        "auto",
        choices=("auto", "linear", "dtw"),
        label="multilinear align",
        help="how a class's units are put on its reference's frames: linear (uniform time scaling), "
        "dtw, or auto (the default: steps linear, whole clips dtw)",
    )
    max_reps: int = option(
        8,
        low=1,
        high=64,
        metavar="R",
        label="multilinear repetitions",
        help="most step units a style gives a tensor (default 8)",
    )
    label: str | None = option(
        None,
        metavar="CLASS",
        label="multilinear label",
        help="the class of the whole recording (default: each stretch's, from the Viterbi search's path)",
    )
    prior: float = option(
        0.05,
        low=0.0,
        label="multilinear prior",
        help="weight pulling a unit's coefficients toward its starting row's (default 0.05)",
    )
    warp: bool = option(
        True,
        negated=("--multilinear-no-warp",),
        label="multilinear warp",
        help="optimise each unit's time warp (default on; --multilinear-no-warp: a uniform one)",
    )
    hold_feet: bool = option(
        False,
        label="multilinear hold feet",
        help="hold the feet the units plant (less skate, a little more joint error; default off)",
    )
    evaluations: int = option(
        60,
        low=4,
        high=10000,
        metavar="N",
        label="multilinear evaluations",
        help="most residual evaluations of a unit's least squares (default 60)",
    )
