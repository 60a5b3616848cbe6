"""What a reconstruction is asked for, as values, and how an option is declared once.

`Options` holds what every strategy reads (the strategy's name, the cost weights, the
live decoder's lag, the heading rule, the annotation constraints), the options several
strategies share (`SharedOptions`: the track pull today) and the chosen strategy's own
options (`own`: an instance of its `options_class`, None for its defaults).

A strategy declares its own options once, as a frozen dataclass whose fields are made by
`option()`: type (from the annotation: int, float, bool, str or tuple[str, ...], each
optionally `| None`), default, range or choices, help text, the command line's extra
names (today's flags) and how messages name it. Everything else is derived from that
declaration: the command-line flags (`graphsvc.flags`), the checks (`check_fields`,
one message style, the field named), the gRPC form (`values_of`, `from_values`: a name
and a map of values) and the report's settings (`Options.to_dict`). A cross-field rule
is the dataclass's own `check()` method.

Plain data and checks, no kernels: the CLI, the service and every strategy import this
without pulling a search in.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import asdict, dataclass, field
from functools import cache
from pathlib import Path

from graphsvc.errors import FormatError, InputError
from graphsvc.fileio import read_json_file
from graphsvc.sensors.recording import validate_constraints

# ---------------------------------------------------------------- declaring options


@dataclass(frozen=True)
class OptionSpec:
    """One declared option (`option()`). kind: int, float, bool, str or tuple (of
    str); optional: None is a value (the option unset: the strategy's own rule);
    low/high: the range (low_open: low itself refused); choices: the allowed values of
    a str; noun: what a valid value is, in messages ("a finite cost"); label: how
    messages name it (default: the field's name); aliases: further command-line
    flags; negated: flags that set a bool option False (`--olng-basic-steps`);
    metavar: the flag's placeholder."""

    name: str
    kind: type
    optional: bool
    default: object
    help: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    choices: tuple | None = None
    noun: str | None = None
    label: str | None = None
    aliases: tuple[str, ...] = ()
    negated: tuple[str, ...] = ()
    metavar: str | None = None

    @property
    def title(self) -> str:
        return self.label or self.name


def option(
    default,
    help: str,
    *,
    low=None,
    high=None,
    low_open: bool = False,
    choices=None,
    noun=None,
    label=None,
    aliases=(),
    negated=(),
    metavar=None,
):
    """A dataclass field declaring an option (module docstring); the type is the field's
    annotation."""
    meta = {
        "option": dict(
            help=help,
            low=low,
            high=high,
            low_open=low_open,
            choices=None if choices is None else tuple(choices),
            noun=noun,
            label=label,
            aliases=tuple(aliases),
            negated=tuple(negated),
            metavar=metavar,
        )
    }
    return field(default=default, metadata=meta)


_KINDS = {int: int, float: float, bool: bool, str: str}


def _kind(hint) -> tuple[type, bool]:
    """(kind, optional) of a field's resolved annotation."""
    args = typing.get_args(hint)
    optional = type(None) in args
    if optional:
        rest = [a for a in args if a is not type(None)]
        if len(rest) != 1:
            raise TypeError(f"an option's type must be one type or None, not {hint}")
        hint = rest[0]
    if typing.get_origin(hint) is tuple:
        if typing.get_args(hint) != (str, Ellipsis):
            raise TypeError(f"a tuple option must be tuple[str, ...], not {hint}")
        return tuple, optional
    if hint not in _KINDS:
        raise TypeError(f"an option's type must be int, float, bool, str or tuple[str, ...], not {hint}")
    return hint, optional


def option_specs(cls: typing.Any) -> tuple[OptionSpec, ...]:
    """The declared options of an options dataclass, in field order."""
    return _declared(cls)


@cache
def _declared(cls: type) -> tuple[OptionSpec, ...]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        meta = f.metadata.get("option")
        if meta is None:
            raise TypeError(f"{cls.__name__}.{f.name} is not declared with option()")
        kind, optional = _kind(hints[f.name])
        out.append(OptionSpec(f.name, kind, optional, f.default, **meta))
    return tuple(out)


# ---------------------------------------------------------------- checking values


class OptionError(InputError):
    """An option's value refused. field: the option's name (a conversion prefixes where
    it came from: `options.ssg.overlap_s`, `--ssg-overlap`)."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(message)


def on_field(exc: Exception, name: str) -> Exception:
    """`exc` marked as caused by option `name` (`option_field`), for a conversion to say
    which field of a request it came from; its type and message unchanged."""
    exc.option_field = name  # type: ignore[attr-defined]  # (an attribute of our own on any exception)
    return exc


def _range_text(spec: OptionSpec) -> str:
    lo, hi = spec.low, spec.high
    if lo is not None and hi is not None and not spec.low_open:
        return f"from {lo:g} to {hi:g}"
    parts = []
    if lo is not None:
        parts.append(f"{'>' if spec.low_open else '≥'} {lo:g}")
    if hi is not None:
        parts.append(f"at most {hi:g}")
    return " and ".join(parts)


def check_value(spec: OptionSpec, value, prefix: str = ""):
    """`value` as option `spec` takes it (an int for an int, a tuple for a tuple), or
    OptionError naming it: "<prefix><label> must be …, got …"."""
    label = f"{prefix}{spec.title}"
    if value is None:
        if spec.optional:
            return None
        raise OptionError(spec.name, f"{label} must be given")
    if spec.kind is bool:
        if not isinstance(value, bool):
            raise OptionError(spec.name, f"{label} must be true or false, got {value!r}")
        return value
    if spec.kind is str:
        if not isinstance(value, str) or not value:
            raise OptionError(spec.name, f"{label} must be {spec.noun or 'a non-empty text'}, got {value!r}")
        if spec.choices is not None and value not in spec.choices:
            raise OptionError(spec.name, f"{label} must be one of {', '.join(spec.choices)}, got {value!r}")
        return value
    if spec.kind is tuple:
        if (
            isinstance(value, str)
            or not isinstance(value, (tuple, list))
            or not value
            or not all(isinstance(v, str) and v for v in value)
        ):
            raise OptionError(spec.name, f"{label} must be {spec.noun or 'a list of names'}, got {value!r}")
        return tuple(value)
    whole = spec.kind is int
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or (whole and value != int(value))
    ):
        noun = spec.noun or ("a whole number" if whole else "a finite number")
        limits = _range_text(spec)
        raise OptionError(spec.name, f"{label} must be {noun}{' ' + limits if limits else ''}, got {value!r}")
    value = int(value) if whole else float(value)
    noun = spec.noun + " " if spec.noun and not whole else ""
    if spec.low is not None and (value <= spec.low if spec.low_open else value < spec.low):
        raise OptionError(
            spec.name, f"{label} must be {noun}{'>' if spec.low_open else '≥'} {spec.low:g}, got {value!r}"
        )
    if spec.high is not None and value > spec.high:
        raise OptionError(spec.name, f"{label} must be {noun}at most {spec.high:g}, got {value!r}")
    return value


def check_fields(obj, prefix: str = "") -> None:
    """Every declared field of an options object checked (`check_value`), then its own
    cross-field rule (`obj.check()`, where it has one). OptionError naming the field."""
    for spec in option_specs(type(obj)):
        check_value(spec, getattr(obj, spec.name), prefix)
    if hasattr(obj, "check"):
        obj.check()


def from_values(cls, values: dict, prefix: str = ""):
    """An options object of `cls` from {field name: value} (absent: the default), each
    value checked and given its declared type (a whole float for an int, a list for a
    tuple). OptionError for an unknown name or a value refused."""
    specs = {s.name: s for s in option_specs(cls)}
    unknown = [k for k in values if k not in specs]
    if unknown:
        raise OptionError(
            unknown[0], f"{prefix}{unknown[0]} is not an option here (options: {', '.join(specs) or 'none'})"
        )
    obj = cls(**{k: check_value(specs[k], v, prefix) for k, v in values.items()})
    check_fields(obj, prefix)
    return obj


def values_of(obj, changed_only: bool = False) -> dict:
    """{field name: value} of an options object (tuples as lists: JSON's form);
    changed_only: only those that differ from their defaults."""
    out = {}
    for spec in option_specs(type(obj)):
        v = getattr(obj, spec.name)
        if changed_only and v == spec.default:
            continue
        out[spec.name] = list(v) if isinstance(v, tuple) else v
    return out


def given_names(owner: str, obj) -> list[str]:
    """The options of `obj` (strategy `owner`'s) set other than their defaults, named
    as a report lists ignored options: the field's own flag for one with a flag of its
    own (`beam`, `markers`), else owner_field (`olng_k`)."""
    out = []
    for spec in option_specs(type(obj)):
        if getattr(obj, spec.name) == spec.default:
            continue
        bare = [a[2:].replace("-", "_") for a in spec.aliases if not a[2:].startswith(f"{owner}-")]
        out.append(bare[0] if bare else f"{owner}_{spec.name}")
    return out


# ---------------------------------------------------------------- what every strategy reads


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
    orientation: float = None  # type: ignore[assignment]  # (None: ORIENTATION_WEIGHT)

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
# The tracker fused with a reconstruction's own root track (`synthesis.track`): its
# white noise σ (m, Kelly et al.'s system's 10 cm) and how fast the rate of the offset
# between the two may change (m/s per √s), chosen on dataset-2's takes 002
# (docs/reconstruction.md).
TRACK_SIGMA_M = 0.10
TRACK_DRIFT = 0.3
# σ (s) of the Gaussian over the output's poses (`synthesis.smooth`), chosen on
# dataset-2's takes 002 (docs/reconstruction.md, *Smoothing*).
SMOOTH_S = 1.0 / 30.0


def track_pull(pull_s: float | None, rate_hz: float) -> float:
    """The share α of the gap to the measured position a reconstruction's placement
    closes each sample, for a time constant of pull_s seconds at rate_hz: 1 − exp(−1 /
    (pull_s · rate)); 0 (never pulled: placed once, at the start) for None or 0."""
    if not pull_s:
        return 0.0
    return float(-math.expm1(-1.0 / (float(pull_s) * float(rate_hz))))


@dataclass(frozen=True)
class SharedOptions:
    """The options several strategies share; a strategy names those it uses
    (`Strategy.shared`), and the others, set, are listed as ignored in its report.
    track_pull_s: the time constant (s) with which a search's paths are placed toward the
    measured positions as it scores them (0: placed once, at the start), and OLNG's
    heading turned toward the measured one. track_sigma_m, track_drift: the tracker's
    noise σ (m) and how fast the rate of the offset between the reconstruction's own root
    track and the tracker may change (m/s per √s), with which the output's root is fused
    with the measured positions (`synthesis.track`). smooth_s: σ (s) of the filter over
    the output's poses (`synthesis.smooth`; 0: off). refine: each frame's pose from a
    local model of the knowledge base around the measured readings (`strategies.refine`)."""

    track_pull_s: float = option(
        TRACK_PULL_S,
        low=0.0,
        label="track pull",
        noun="a finite number of seconds",
        aliases=("--track-pull",),
        metavar="S",
        help="time constant (s) with which the search's paths are placed toward the measured "
        "positions as it scores them, and OLNG's heading turned toward the measured one "
        f"(0: placed once, at the start; default {TRACK_PULL_S:g})",
    )
    track_sigma_m: float = option(
        TRACK_SIGMA_M,
        low=0.0,
        low_open=True,
        label="track sigma",
        noun="a finite number of metres",
        metavar="M",
        aliases=("--track-sigma",),
        help="the overhead tracker's white noise σ, m, with which the output's root is "
        f"fused with the measured positions (default {TRACK_SIGMA_M:g})",
    )
    track_drift: float = option(
        TRACK_DRIFT,
        low=0.0,
        label="track drift",
        noun="a finite number",
        metavar="D",
        help="how fast the rate of the offset between the reconstruction's own root track and "
        "the tracker may change, m/s per √s (0: one constant rate; default "
        f"{TRACK_DRIFT:g})",
    )
    smooth_s: float = option(
        SMOOTH_S,
        low=0.0,
        label="smoothing",
        noun="a finite number of seconds",
        metavar="S",
        aliases=("--smooth",),
        help="σ (s) of the Gaussian over the output's poses that removes frame-to-frame jitter; a "
        f"live stream waits about 3σ longer (0: off; default {SMOOTH_S:.3g})",
    )
    refine: bool = option(
        True,
        label="refinement",
        help="each frame's pose from a local linear model of the knowledge-base frames whose readings "
        "move as the measured ones do, on the strategy's root (default on)",
    )


@dataclass(frozen=True)
class NoOptions:
    """The options of a strategy that has none of its own."""


# Where an older Options field name lives now, set by the registry (graphsvc.strategies,
# always imported before this module): name → ("shared", field), ("strategy", name) or
# ("option", strategy, field) — a shared option (track_pull_s), a strategy's own options
# by its name (olng, ssg), a strategy option by its own flag (beam) — or None.
LEGACY_NAMES: typing.Any = None  # (a function once the registry has loaded)


@dataclass(frozen=True, init=False)
class Options:
    """How to reconstruct. strategy: a registered name (`graphsvc.strategies`).
    weights: Kelly et al. 2013, eq. 6 (per g², per m, per rad). latency_s: fixed lag (s)
    of the live decoder; None in batch = the whole input at once. heading_from_track:
    derive the heading from the ground positions (Kelly et al. 2013, §6: direction of
    travel above `speed_threshold` m/s, else `rest_heading_deg`). constraints:
    annotation constraint sets in priority order (None: the recording's own). shared:
    the options several strategies share (`SharedOptions`). settings: the own options
    given for each strategy, by name (a strategy's `options_class` instance; the others'
    are listed as ignored in a report). own: shorthand for the chosen strategy's entry
    of settings (the property `own` reads it; None: its defaults).

    The fields of older versions (`beam`, `track_pull_s`, `olng`, `ssg`) are still read
    and taken as keywords (`LEGACY_NAMES`): deprecated, for existing callers."""

    strategy: str = "viterbi"
    weights: Weights = Weights()
    latency_s: float | None = None
    heading_from_track: bool = False
    rest_heading_deg: float = 0.0
    speed_threshold: float = 2.0
    constraints: tuple | None = None
    shared: SharedOptions = SharedOptions()
    settings: tuple = ()  # ((strategy name, its options), ...) sorted by name

    def __init__(
        self,
        strategy: str = "viterbi",
        weights: Weights = Weights(),
        latency_s: float | None = None,
        heading_from_track: bool = False,
        rest_heading_deg: float = 0.0,
        speed_threshold: float = 2.0,
        constraints: tuple | None = None,
        shared: SharedOptions = SharedOptions(),
        settings=(),
        own=None,
        **legacy,
    ):
        settings = dict(settings.items() if isinstance(settings, dict) else settings)
        if own is not None:
            settings[strategy] = own
        for key, value in legacy.items():
            where = LEGACY_NAMES(key) if LEGACY_NAMES is not None else None
            if where is None:
                raise TypeError(f"Options got an unexpected keyword argument {key!r}")
            if where[0] == "shared":
                shared = dataclasses.replace(shared, **{where[1]: value})
            elif where[0] == "strategy":
                settings[where[1]] = value
            else:
                _, name, field_name = where
                settings[name] = dataclasses.replace(
                    settings.get(name) or LEGACY_NAMES(name, default=True), **{field_name: value}
                )
        for name, value in (
            ("strategy", strategy),
            ("weights", weights),
            ("latency_s", latency_s),
            ("heading_from_track", heading_from_track),
            ("rest_heading_deg", rest_heading_deg),
            ("speed_threshold", speed_threshold),
            ("constraints", constraints),
            ("shared", shared),
            ("settings", tuple(sorted(settings.items(), key=lambda kv: str(kv[0])))),
        ):
            object.__setattr__(self, name, value)

    def __getattr__(self, name: str):
        # (only for names the instance lacks: an older field name, `LEGACY_NAMES`)
        where = LEGACY_NAMES(name) if LEGACY_NAMES is not None and not name.startswith("__") else None
        if where is None:
            raise AttributeError(f"'Options' object has no attribute {name!r}")
        if where[0] == "shared":
            return getattr(self.shared, where[1])
        own = self.of(where[1]) or LEGACY_NAMES(where[1], default=True)
        return own if where[0] == "strategy" else getattr(own, where[2])

    @property
    def own(self):
        """The chosen strategy's own options, or None (its defaults)."""
        return dict(self.settings).get(self.strategy)

    def of(self, name: str):
        """The own options given for strategy `name`, or None."""
        return dict(self.settings).get(name)

    def to_dict(self) -> dict:
        """The settings as a report shows them: what every strategy reads, the shared
        options and the chosen strategy's own (`values_of`), in one object."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("shared", "settings")}
        d["weights"] = asdict(self.weights)
        d["constraints"] = None if self.constraints is None else list(self.constraints)
        d.update(values_of(self.shared))
        if self.own is not None:
            d.update(values_of(self.own))
        return d


def check_common(options: Options) -> None:
    """InputError for values of what every strategy reads, or of the shared options,
    that no strategy accepts (the strategy's own: `strategies.check_options`)."""
    w = options.weights
    for name in ("acc", "position", "heading", "orientation"):
        v = getattr(w, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"weight {name} must be a finite number ≥ 0, got {v!r}")
    if w.acc == w.position == w.heading == w.orientation == 0:
        raise InputError("weights are all 0: every path would cost the same; give at least one weight > 0")
    if options.latency_s is not None and (not math.isfinite(options.latency_s) or options.latency_s < 0):
        raise InputError(f"latency must be a finite number of seconds ≥ 0, got {options.latency_s}")
    if not isinstance(options.shared, SharedOptions):
        raise InputError(f"shared options must be SharedOptions, got {type(options.shared).__name__}")
    check_fields(options.shared)
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


# ---------------------------------------------------------------- annotation constraints


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
                raise InputError(
                    f"constraint set {i}: constraints {j0} ({s0:g}–{e0:g} s) and {j1} ({s1:g}–{e1:g} s) overlap"
                )
    if graph is not None:
        for k, cset in enumerate(constraints):
            for item in cset:
                label = item["require"].get("label")
                if label is not None and label not in graph.labels:
                    raise InputError(
                        f"constraint set {k}: unknown label {label!r} (graph labels: {', '.join(graph.labels)})"
                    )
    return constraints


def load_constraints(path) -> list:
    """A constraint file: a JSON list of sets in priority order (see `Recording`)."""
    path = Path(path)
    data = read_json_file(path)
    try:
        return check_constraints(data)
    except InputError as exc:
        raise FormatError(path, str(exc)) from None
