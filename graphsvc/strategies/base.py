"""The interface every reconstruction strategy implements (`Strategy`).

A strategy turns a recording into motion on a graph's skeleton. It:

- declares its own options (`options_class`, a dataclass of `options.option()` fields:
  the CLI's flags, the checks, the gRPC form and the report's settings are derived
  from it) and the shared options it uses (`shared`: names of `SharedOptions` fields);
- declares the inputs it needs (`needs`: a recording without one is refused, naming
  it) and those it can use (`uses`: the others are ignored and the report lists them
  under `ignored_inputs`), from INPUTS;
- prepares an index from a graph (`prepare`: built on first use, held for the graph
  object; a strategy whose index is costly caches it beside the graph file, keyed by
  the file's checksum — `strategies.index`);
- reconstructs a whole recording (`reconstruct`), given the recording already
  checked and put on the graph's sample grid (`strategies.inputs.prepare_input`);
- opens a live session (`session_class`, a `strategies.live.LiveSession`:
  `push(sample) -> frames`, `flush()`), after checking what a stream announces
  (`check_stream`);
- hides clips for leave-one-out evaluation (`allowed_mask`: for the graph strategies a
  node mask, `graph.holdout.held_out_mask`), and says how an evaluation simulates its
  input from a clip (`simulate_input`, `describe_input`).

The hooks have defaults that fit a strategy reading body-worn accelerometers; a
strategy overrides what it does differently. What strategies share lives beside this
module: the checks and resampling of a recording (`inputs`), where a reconstruction
starts (`start`), the result types (`results`) and the live session's sample handling
(`live`), so a strategy writes only its own decoding.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.derived import derived
from graphsvc.graph.holdout import held_out_mask
from graphsvc.graph.model import MotionGraph
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.options import NoOptions, Options, SharedOptions, check_fields, given_names, values_of

INPUTS = ("accelerations", "orientations", "markers", "ground_position", "heading", "constraints")


class Strategy:
    """One way to reconstruct motion (module docstring). Subclasses set `name`, `needs`,
    `uses`, `summary`, `options_class` and `shared`, and implement `prepare`,
    `reconstruct` and `session_class`."""

    name: str = ""
    needs: frozenset = frozenset()
    uses: frozenset = frozenset()
    summary: str = ""
    options_class: type = NoOptions
    shared: frozenset = frozenset()  # the SharedOptions fields it reads
    session_class: type = None  # a LiveSession subclass

    # ------------------------------------------------------------ options

    def own(self, options: Options):
        """The strategy's own options in `options` (its defaults where none were given)."""
        return self.options_class() if options.own is None else options.own

    def check_own(self, own) -> None:
        """InputError (an `options.OptionError` naming the field) for own options no
        input accepts: every declared field's type and range, then the options' own
        cross-field rule."""
        if not isinstance(own, self.options_class):
            raise InputError(f"strategy {self.name!r} takes {self.options_class.__name__}, got {type(own).__name__}")
        check_fields(own)

    def ignored_options(self, options: Options) -> list[str]:
        """Options set to something this strategy does not use (for the report): shared
        options it does not read and other strategies' own options, set other than their
        defaults (`options.given_names`)."""
        out = [k for k in values_of(options.shared, changed_only=True) if k not in self.shared]
        for name, other in options.settings:
            if name != self.name:
                out += given_names(name, other)
        return sorted(out)

    def to_wire(self, own):
        """Own options as a client sends them to a server (which reads no files of the
        client's: a value that names a file goes as the file's content); as given by
        default."""
        return own

    def check_wire(self, values: dict, chosen: bool) -> None:
        """InputError (`options.on_field` naming the field) for own option values from a
        client that a server cannot take — one naming a file of the server's, say —
        before they are parsed; chosen: the request's strategy is this one (not only
        options given for it)."""

    def options_for_recording(self, options: Options, rec) -> Options:
        """The options to send with a recording, where what the recording is changes
        them (e.g. SSG's marker set named by a simulated recording); by default as given."""
        return options

    # ------------------------------------------------------------ batch and live

    def prepare(self, graph: MotionGraph):
        """The strategy's index for `graph`, made once per graph object."""
        raise NotImplementedError

    def reconstruct(
        self,
        index,
        graph: MotionGraph,
        inp,
        options: Options,
        allowed: np.ndarray | None = None,
        threads: bool = True,
        should_stop=None,
    ):
        """A `results.Reconstruction` of `inp` (a `inputs.PreparedInput`)."""
        raise NotImplementedError

    def warm_up(self, index, graph: MotionGraph, threads: bool = False) -> None:
        """Load compiled code and make tables now, not on a client's first sample."""

    def describe_lag(self, rate_hz: float) -> str:
        """How far a live session's poses trail their samples, for a live command's help
        (`--latency S` is the search's own lag where there is one); by default none."""
        return "at once, whatever S"

    def check_stream(self, options: Options, sensor_names, marker_names) -> None:
        """InputError for what a live stream announces before its first sample that the
        strategy cannot read (its marker names, say), with `options.on_field` naming the
        announcement's field ("marker_names", "sensor_names")."""

    # ------------------------------------------------------------ evaluation

    def allowed_mask(self, graph: MotionGraph, clips) -> np.ndarray:
        """(N,) bool: the nodes a search may use when graph clips `clips` (their
        performances) are held out."""
        return held_out_mask(graph, clips)

    def check_simulation(self, options: Options) -> None:
        """InputError, before an evaluation builds anything, when `simulate_input` could
        not make this strategy's input with these options."""

    def simulate_input(
        self, motion, layout, options: Options, noise, seed: int, rate_hz: float, mapping=None, pattern=None
    ):
        """The recording an evaluation reconstructs a test clip from: by default the
        layout's accelerometers (and the tracker, where the noise model keeps it)."""
        return simulate_recording(motion, layout, noise, seed=seed, rate_hz=rate_hz, mapping=mapping)

    def describe_input(self, options: Options, noise, pattern=None) -> str:
        """What `simulate_input` makes (with `pattern`, how markers are lost), for an
        evaluation's summary line; "" for the accelerometers of the graph's layout."""
        return ""


def frame_by_frame_ignored(options: Options) -> list[str]:
    """The options a strategy that decides each frame from its own sample ignores:
    the latency (no search over time to delay)."""
    return ["latency_s"] if options.latency_s is not None else []


def prepared_index(strategy: Strategy, graph: MotionGraph):
    """`strategy.prepare(graph)`, once per graph object and strategy (`graph.derived`:
    an index must not refer to its graph but weakly)."""
    return derived(graph, ("strategy index", strategy.name), lambda: strategy.prepare(graph))


__all__ = ["INPUTS", "SharedOptions", "Strategy", "frame_by_frame_ignored", "prepared_index"]
