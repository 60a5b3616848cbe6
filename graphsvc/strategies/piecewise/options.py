"""The piecewise strategy's own options (Xie 2009, §5–6), declared once with
`options.option()`: flags, checks, the gRPC form and the report's settings are derived
from them. The checks that need the knowledge base (the reduced dimension against the
pose's, the clusters against its frames) are made where the model is learned
(`model.check_against`)."""

from __future__ import annotations

from dataclasses import dataclass

from graphsvc.strategies.options import OptionError, option

METHODS = ("rbf", "rbf-fit", "optimise")
REDUCTIONS = ("pca", "lle")
ASSIGNMENTS = ("nearest", "mixture")
MAX_CLUSTERS = 4096


@dataclass(frozen=True)
class PiecewiseOptions:
    """method: a pose from the sample's cluster's normalised RBF over its frames nearest
    the readings (rbf), from the cluster's fitted RBF map of Xie eq. 5.9 (rbf-fit), or
    from the per-frame optimisation of eq. 6.2–6.4 with its prior centred on the rbf
    estimate (optimise); reduce: how poses are reduced
    (pca, or lle: landmark LLE); dims: the reduced dimension (None: the fewest PCA
    components holding 99.9 % of the pose variance); clusters: the GMM's components, a
    count or "auto" (the fewest-BIC count of a ladder); assign: how a sample finds its
    cluster (nearest: the cluster of the knowledge-base frame whose readings are
    nearest; mixture: Xie's, the mixture's marginal over the readings); width: the
    RBF kernel width σ in g (None: each cluster's own, from the spacing of its
    readings); w_smooth, w_control: the optimisation's smoothness and control weights
    (ω_s, ω_c: 0.2 and 0.8, Xie's)."""

    method: str = option(
        "rbf",
        choices=METHODS,
        label="piecewise method",
        help="pose from the cluster's normalised RBF over its frames nearest the readings (rbf, the "
        "default), its fitted RBF map of Xie eq. 5.9 (rbf-fit) or the per-frame optimisation "
        "(optimise)",
    )
    reduce: str = option(
        "pca",
        choices=REDUCTIONS,
        label="piecewise reduce",
        help="how poses are reduced before clustering: pca (the default) or lle (landmark LLE)",
    )
    dims: int | None = option(
        None,
        low=1,
        high=256,
        metavar="D",
        label="piecewise dims",
        help="reduced pose dimension, below the pose's own (default: the fewest holding 99.9 "
        "percent of the pose variance)",
    )
    clusters: str = option(
        "auto",
        label="piecewise clusters",
        metavar="K|auto",
        noun="a whole number ≥ 1 or auto",
        help="GMM clusters: a count, or auto to pick the count by BIC (default auto)",
    )
    assign: str = option(
        "nearest",
        choices=ASSIGNMENTS,
        label="piecewise assign",
        help="how a sample finds its cluster: the cluster of the knowledge-base frame with the nearest "
        "readings (nearest, the default) or the mixture's marginal over the readings (mixture, "
        "Xie's)",
    )
    width: float | None = option(
        None,
        low=0.0,
        low_open=True,
        metavar="SIGMA",
        label="piecewise width",
        noun="a finite width in g",
        help="RBF kernel width σ in g (default: each cluster's, from its readings' spacing)",
    )
    w_smooth: float = option(
        0.2, low=0.0, label="piecewise smoothness weight", help="optimise: smoothness weight ω_s (default 0.2)"
    )
    w_control: float = option(
        0.8, low=0.0, label="piecewise control weight", help="optimise: control weight ω_c (default 0.8)"
    )

    def check(self) -> None:
        self.cluster_count()

    def cluster_count(self) -> int | None:
        """The clusters asked for (None: auto). OptionError for anything else."""
        text = self.clusters.strip()
        if text == "auto":
            return None
        if not text.isdigit() or not 1 <= int(text) <= MAX_CLUSTERS:
            raise OptionError(
                "clusters",
                f"piecewise clusters must be a whole number from 1 to {MAX_CLUSTERS} or auto, got {self.clusters!r}",
            )
        return int(text)
