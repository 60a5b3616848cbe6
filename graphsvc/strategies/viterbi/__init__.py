"""The Viterbi graph search as a strategy (Kelly et al. 2013): the path through the
motion graph that best explains the accelerometers, the overhead tracker's ground
position and heading and the animator's constraints, synthesized on the
knowledge-base skeleton.

- `options`: its own options (`ViterbiOptions`: the beam).
- `strategy`: the strategy (batch reconstruction) and its live session; `STRATEGY`, the
  instance the registry registers.
- `costs`: the cost terms L(e, t) = W_A·C_A + W_P·C_P + W_O·C_O and the path state
  they read, with the list of every place each term is computed.
- `tables`: the graph's arrays in the search's layouts (`SearchIndex`).
- `dense`: the exact step's passes over every node and edge, float32 and float64.
- `beam`: the beam search's sparse step and cut (kernels).
- `beam_search`: a search's beam side (`BeamSteps`: setup, sparse or dense, the cut and
  the bound, the rows a sparse step resets).
- `store`: the survivor store and the walks back through the dense rows.
- `search`: `ViterbiSearch`, the incremental search a batch or live caller steps.
- `batch`: the batch search, constraint sets, per-term path costs, the warm-up.
- `stream`: the fixed-lag and sliding-window decoders of live streams.
- `reference`: a plain numpy search over the full lattice, which the others are
  checked against.
- `intrinsics`: LLVM instructions for the hot loops; the threaded and serial compile.
"""

from graphsvc.strategies.viterbi.options import ViterbiOptions
from graphsvc.strategies.viterbi.strategy import STRATEGY, ViterbiSession, ViterbiStrategy, warm_up

__all__ = ["STRATEGY", "ViterbiOptions", "ViterbiSession", "ViterbiStrategy", "warm_up"]
