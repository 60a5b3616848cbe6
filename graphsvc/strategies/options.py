"""What a reconstruction is asked for, as values: the cost weights, the options every
strategy shares and those only some use, and the annotation constraints.

Plain data and checks, no kernels: the CLI, the service and every strategy import these
without pulling a search in. A strategy uses the options that mean something to it
and names the others it ignored in its report (`ignored_options`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

from graphsvc.errors import FormatError, InputError
from graphsvc.sensors.recording import validate_constraints


@dataclass(frozen=True)
class Weights:
    """Kelly et al. 2013, eq. 6: accelerometers (per g²), position (per metre), heading
    (per radian); and sensor orientation (per chord², ≈ rad², of each sensor's tilt
    against the path's: `strategies.viterbi.costs`), which counts only where the
    recording has orientations and the graph their metadata. A strategy weighs
    whichever of these terms it has."""

    acc: float = 1.0
    position: float = 1.0
    heading: float = 1.0
    orientation: float = None  # type: ignore[assignment]  (None: ORIENTATION_WEIGHT)

    def __post_init__(self):
        if self.orientation is None:
            object.__setattr__(self, "orientation", ORIENTATION_WEIGHT)


# The default weight of the sensor-orientation term (per chord², against W_A per g²);
# chosen on Bandai dataset-2's takes 002 with real-IMU noise (docs/search.md), not on
# the clips the accuracy table reports.
ORIENTATION_WEIGHT = 1.0


# The default time constant of the pull toward the tracker (s); chosen on Bandai
# dataset-2's takes 002 with the takes held out (docs/reconstruction.md), not on the clips
# the accuracy table reports.
TRACK_PULL_S = 0.5


@dataclass(frozen=True)
class OlngOptions:
    """The OLNG strategy's settings (Tautges et al. 2011; defaults from the paper). k: neighbours a
    sample (None: the paper's share of the knowledge base, 4096 of about 600,000
    frames, i.e. frames / 150, at least 16 and at most 4096); m: window columns; i:
    paths the pose is made from (None: the paper's K / 16, at least 4 and at most 256);
    extended: the extended steps (a column skipped, two to four frames on);
    w_prior, w_contr, w_pose, w_motion, w_smooth: the energy's weights (eq. 2–11);
    fix_feet: while the neighbourhood has a foot in contact, let it move only as the
    neighbours' feet moved (off by default: on Bandai dataset-2's takes 002, the tuning
    set, it cost 0.6 cm of mean joint error, 1.0 cm on gestures)."""

    k: int | None = None
    m: int = 32
    i: int | None = None
    extended: bool = True
    w_prior: float = 5.0
    w_contr: float = 1.0
    w_pose: float = 0.6
    w_motion: float = 0.2
    w_smooth: float = 0.2
    fix_feet: bool = False

    def resolved(self, frames: int) -> "OlngOptions":
        """K and I filled in for a knowledge base of `frames` frames."""
        k = self.k if self.k is not None else min(frames, 4096, max(16, round(frames / 150)))
        i = self.i if self.i is not None else min(k, 256, max(4, k // 16))
        return OlngOptions(k, self.m, i, self.extended, self.w_prior, self.w_contr, self.w_pose, self.w_motion,
                           self.w_smooth, self.fix_feet)  # fmt: skip


def check_olng(o: "OlngOptions") -> None:
    """InputError for OLNG settings no knowledge base accepts (K against the frames is
    checked where the index is known)."""
    for name in ("k", "m", "i"):
        v = getattr(o, name)
        if v is None and name != "m":
            continue
        if isinstance(v, bool) or not isinstance(v, int):
            raise InputError(f"OLNG {name.upper()} must be a whole number, got {v!r}")
    if o.k is not None and o.k < 1:
        raise InputError(f"OLNG K must be ≥ 1, got {o.k}")
    if o.m < 2:
        raise InputError(f"OLNG M must be ≥ 2 (a path needs two columns), got {o.m}")
    if o.i is not None and (o.i < 1 or (o.k is not None and o.i > o.k)):
        raise InputError(f"OLNG I must be between 1 and K ({o.k if o.k is not None else 'its default'}), got {o.i}")
    for name in ("w_prior", "w_contr", "w_pose", "w_motion", "w_smooth"):
        v = getattr(o, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"OLNG weight {name[2:]} must be a finite number ≥ 0, got {v!r}")
    if o.w_prior * (o.w_pose + o.w_motion + o.w_smooth) + o.w_contr <= 0:
        raise InputError("OLNG weights are all zero: the pose would be undetermined")


SSG_OFFSETS = ("auto", "fit", "nominal")


@dataclass(frozen=True)
class SsgOptions:
    """The SSG strategy's settings (Tautges 2012, ch. 4). markers: the marker set — a
    built-in name (hands-feet, left-foot, head-back, vicon), a JSON/TOML file, or a set
    as JSON text (None: the one the recording names, as `simulate --markers` writes);
    keep: the markers to use (None: every marker of the set the recording has);
    window_s, overlap_s: a window's length and consecutive windows' overlap (thesis: N =
    20 and o = 10 frames at 60 Hz, 0.33 s and 0.17 s; 15 and 6, 0.25 s and 0.1 s, for
    markers on the head and trunk only — None picks by the kept markers); k:
    subsequences a window (8; 16 for head and trunk); weight: the transition costs'
    weight against the node costs (1; 4 for head and trunk, whose windows say less of
    the limbs: the thesis raises it there); offsets: the markers' offsets on their
    segments — "nominal" (the set's), "fit" (estimated from the input against the
    knowledge-base poses it is matched to, `strategies.ssg.offsets`), "auto" (fit
    unless the recording was simulated by graphsvc with this set)."""

    markers: str | None = None
    keep: tuple[str, ...] | None = None
    window_s: float | None = None
    overlap_s: float | None = None
    k: int | None = None
    weight: float | None = None
    offsets: str = "auto"

    def resolved(self, trunk_only: bool) -> "SsgOptions":
        """The defaults filled in for a set whose kept markers are (not) all on the head
        and trunk."""
        d = (0.25, 0.1, 16, 4.0) if trunk_only else (1.0 / 3.0, 1.0 / 6.0, 8, 1.0)
        pick = lambda v, default: default if v is None else v  # noqa: E731
        return SsgOptions(self.markers, self.keep, pick(self.window_s, d[0]), pick(self.overlap_s, d[1]),
                          pick(self.k, d[2]), pick(self.weight, d[3]), self.offsets)  # fmt: skip


def check_ssg(o: "SsgOptions") -> None:
    """InputError for SSG settings no input accepts."""
    for name in ("window_s", "overlap_s", "weight"):
        v = getattr(o, name)
        if v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"SSG {name.replace('_s', '').replace('_', ' ')} must be a finite number ≥ 0, got {v!r}")
    if o.window_s is not None and o.window_s <= 0:
        raise InputError(f"SSG window must be > 0 seconds, got {o.window_s}")
    if o.window_s is not None and o.overlap_s is not None and o.overlap_s > 0.5 * o.window_s:
        raise InputError(f"SSG overlap ({o.overlap_s:g} s) must be at most half the window ({o.window_s:g} s)")
    if o.k is not None and (isinstance(o.k, bool) or not isinstance(o.k, int) or not 1 <= o.k <= 256):
        raise InputError(f"SSG k must be a whole number from 1 to 256, got {o.k!r}")
    if o.offsets not in SSG_OFFSETS:
        raise InputError(f"SSG offsets must be one of {', '.join(SSG_OFFSETS)}, got {o.offsets!r}")
    if o.keep is not None and (not isinstance(o.keep, tuple) or not all(isinstance(n, str) and n for n in o.keep)):
        raise InputError("SSG keep must be marker names")
    if o.markers is not None and (not isinstance(o.markers, str) or not o.markers):
        raise InputError("SSG markers must name a marker set")


@dataclass(frozen=True)
class Options:
    """How to reconstruct. strategy: a registered name (`graphsvc.strategies`).
    weights: Kelly et al. 2013, eq. 6 (per g², per m, per rad). latency_s: fixed lag (s) of the live
    decoder; None in batch = the whole input at once. heading_from_track: derive the
    heading from the ground positions (Kelly et al. 2013, §6: direction of travel above
    `speed_threshold` m/s, else `rest_heading_deg`). constraints: annotation constraint
    sets in priority order (None: the recording's own). beam (Viterbi): a cost; after
    each sample only the paths within it of the best one go on (faster on built
    graphs, no longer always the cheapest path; None: the exact search). track_pull_s
    (Viterbi): the time constant (s) with which each path's ground placement is pulled
    toward the measured positions, so the path and the synthesized root follow the
    tracker instead of drifting from where they started (0: placed once, at the
    start); OLNG pulls its root (and heading) the same way. olng: the OLNG strategy's
    settings (`OlngOptions`); ssg: the SSG strategy's (`SsgOptions`)."""

    strategy: str = "viterbi"
    weights: Weights = Weights()
    latency_s: float | None = None
    heading_from_track: bool = False
    rest_heading_deg: float = 0.0
    speed_threshold: float = 2.0
    constraints: tuple | None = None
    beam: float | None = None
    track_pull_s: float = TRACK_PULL_S
    olng: OlngOptions = OlngOptions()
    ssg: SsgOptions = SsgOptions()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["constraints"] = None if self.constraints is None else list(self.constraints)
        return d


def check_options(options: Options) -> None:
    """InputError for values no strategy accepts; InputError or
    StrategyNotImplementedError for a strategy name that is unknown or not built."""
    from graphsvc.strategies import get

    get(options.strategy)
    w = options.weights
    for name in ("acc", "position", "heading", "orientation"):
        v = getattr(w, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"weight {name} must be a finite number ≥ 0, got {v!r}")
    if w.acc == w.position == w.heading == w.orientation == 0:
        raise InputError("weights are all 0: every path would cost the same; give at least one weight > 0")
    if options.latency_s is not None and (not math.isfinite(options.latency_s) or options.latency_s < 0):
        raise InputError(f"latency must be a finite number of seconds ≥ 0, got {options.latency_s}")
    if options.beam is not None and (isinstance(options.beam, bool) or not isinstance(options.beam, (int, float))
                                     or not math.isfinite(options.beam) or options.beam <= 0):
        raise InputError(f"beam must be a finite cost > 0, got {options.beam!r}")
    p = options.track_pull_s
    if isinstance(p, bool) or not isinstance(p, (int, float)) or not math.isfinite(p) or p < 0:
        raise InputError(f"track pull must be a finite number of seconds ≥ 0, got {p!r}")
    if not isinstance(options.olng, OlngOptions):
        raise InputError(f"olng options must be OlngOptions, got {type(options.olng).__name__}")
    check_olng(options.olng)
    if not isinstance(options.ssg, SsgOptions):
        raise InputError(f"ssg options must be SsgOptions, got {type(options.ssg).__name__}")
    check_ssg(options.ssg)
    if not math.isfinite(options.rest_heading_deg):
        raise InputError(f"rest heading must be finite, got {options.rest_heading_deg}")
    if not (math.isfinite(options.speed_threshold) and options.speed_threshold >= 0):
        raise InputError(f"speed threshold must be finite and ≥ 0, got {options.speed_threshold}")


def parse_weights(text: str) -> Weights:
    """'A,P,O' or 'A,P,O,R' (non-negative numbers) → Weights; without R, the default
    orientation weight."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise InputError(f"weights must be three or four numbers A,P,O[,R], got {text!r}") from None
    if len(values) not in (3, 4) or not all(math.isfinite(v) and v >= 0 for v in values):
        raise InputError(f"weights must be three or four finite numbers ≥ 0 as A,P,O[,R], got {text!r}")
    if len(values) == 3 and not any(values):  # the default R counts only where a recording has orientations
        raise InputError(f"weights {text!r} are all 0: give at least one of A,P,O > 0 (or R, as A,P,O,R)")
    return Weights(*values)


def check_constraints(constraints, graph=None) -> list:
    """Validate constraint sets (see `Recording`): structure, 0 ≤ start < end, no two
    intervals of one set overlapping (they would ask for two things at once), and —
    given a graph — labels it has."""
    if isinstance(constraints, tuple):
        constraints = list(constraints)
    validate_constraints(constraints)  # InputError for anything but a list of sets (a JSON number, say)
    for i, cset in enumerate(constraints):
        spans = sorted((float(c["start_s"]), float(c["end_s"]), j) for j, c in enumerate(cset))
        for (s0, e0, j0), (s1, e1, j1) in zip(spans, spans[1:]):
            if s1 <= e0:
                raise InputError(f"constraint set {i}: constraints {j0} ({s0:g}–{e0:g} s) and {j1} ({s1:g}–{e1:g} s) overlap")
    if graph is not None:
        for k, cset in enumerate(constraints):
            for item in cset:
                label = item["require"].get("label")
                if label is not None and label not in graph.labels:
                    raise InputError(f"constraint set {k}: unknown label {label!r} (graph labels: "
                                     f"{', '.join(graph.labels)})")  # fmt: skip
    return constraints


def load_constraints(path) -> list:
    """A constraint file: a JSON list of sets in priority order (see `Recording`)."""
    from graphsvc.fileio import read_json_file

    path = Path(path)
    data = read_json_file(path)
    try:
        return check_constraints(data)
    except InputError as exc:
        raise FormatError(path, str(exc)) from None
