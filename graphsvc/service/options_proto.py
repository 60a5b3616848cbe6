"""A reconstruction's options ↔ `SynthesisOptions`, for every strategy alike.

A strategy and its own options go by name: `strategy_name` and `strategy_settings` (a
Struct of its declared fields, `strategies.options.values_of` / `from_values`), the
shared options as `shared_settings`. Nothing here knows a strategy: what a field is
comes from the strategy's declaration, so a strategy installed as a plug-in crosses the
wire with no edit here.

The deprecated forms are read and written from the same declarations: the enum
`strategy` (STRATEGY_<NAME>), the flat `beam` (a field's own flag, `--beam`), and the
oneof message named after a strategy (ViterbiOptions, OlngOptions, SsgOptions), whose
fields are the strategy's own by name, a declared negation (`basic_steps`), a shared
option (`track_pull_s`) or what every strategy reads (the heading rule). A server reads
the named form when it is there, else the oneof message, else the flat fields; a
client writes all three, so a server that knows only the old form still understands.

Every value is checked by the declarations' checks; a refused one is a `FieldError`
naming its path in the request (`options.ssg.overlap_s`, `options.strategy_settings.k`).
"""

from __future__ import annotations

import math

from graphsvc.errors import FieldError, GraphsvcError, InputError
from graphsvc.sensors.recording import Recording, validate_constraints
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.strategies import DEFAULT, available, get
from graphsvc.strategies.options import Options, SharedOptions, Weights, from_values, option_specs, values_of

# SynthesisOptions' own fields for what every strategy reads (proto name → Options field),
# which a strategy's old message may carry too (ViterbiOptions).
COMMON = {
    "heading_from_track": "heading_from_track",
    "rest_heading_deg": "rest_heading_deg",
    "speed_threshold_m_s": "speed_threshold",
}
ONEOF = "strategy_options"
ENUM_PREFIX = "STRATEGY_"
CONTACT_NAMES = {
    pb.CONTACT_STATE_LEFT: "left",
    pb.CONTACT_STATE_RIGHT: "right",
    pb.CONTACT_STATE_BOTH: "both",
    pb.CONTACT_STATE_NONE: "none",
}
CONTACT_VALUES = {v: k for k, v in CONTACT_NAMES.items()}


def _legacy_names() -> set[str]:
    return {f.name for f in pb.SynthesisOptions.DESCRIPTOR.oneofs_by_name[ONEOF].fields}


def strategy_enum_value(name: str) -> int | None:
    """The deprecated enum's value for strategy `name`, or None where it has none."""
    key = ENUM_PREFIX + name.upper()
    return pb.Strategy.Value(key) if key in pb.Strategy.keys() else None


def strategy_from_enum(value: int, field: str) -> str | None:
    """The strategy the deprecated enum names (None: unspecified); FieldError for a value
    the enum does not have."""
    if value not in pb.Strategy.values():
        known = ", ".join(f"{n[len(ENUM_PREFIX) :]} = {v}" for n, v in pb.Strategy.items() if v)
        raise FieldError(field, f"unknown strategy {value} ({known})")
    if value == 0:
        return None
    return pb.Strategy.Name(value)[len(ENUM_PREFIX) :].lower()


def _negations(cls) -> dict[str, str]:
    """{proto field name: bool option} for declared negating flags (--olng-basic-steps
    → basic_steps), whatever strategy prefixes them."""
    out = {}
    for spec in option_specs(cls):
        for flag in spec.negated:
            out[flag[2:].split("-", 1)[-1].replace("-", "_")] = spec.name
    return out


def _flat_aliases() -> dict[str, tuple[str, str]]:
    """{flat SynthesisOptions field: (strategy, option)} for the options whose own flag
    names a flat field (`--beam` → beam)."""
    flat = {f.name for f in pb.SynthesisOptions.DESCRIPTOR.fields}
    out = {}
    for name in available():
        for spec in option_specs(get(name).options_class):
            for flag in spec.aliases:
                key = flag[2:].replace("-", "_")
                if key in flat:
                    out[key] = (name, spec.name)
    return out


# ---------------------------------------------------------------- constraints


def constraints_to_proto(constraint_sets: list) -> list[pb.ConstraintSet]:
    """Constraint sets as in a Recording / constraint file → protos."""
    out = []
    for cset in constraint_sets:
        msg = pb.ConstraintSet()
        for c in cset:
            ((key, value),) = c["require"].items()
            item = msg.constraints.add(start_s=float(c["start_s"]), end_s=float(c["end_s"]))
            if key == "contact":
                item.contact = CONTACT_VALUES[value]
            else:
                item.label = value
        out.append(msg)
    return out


def constraints_from_proto(sets, field: str) -> list:
    out = []
    for i, cset in enumerate(sets):
        items = []
        for j, c in enumerate(cset.constraints):
            where = f"{field}[{i}].constraints[{j}]"
            for key in ("start_s", "end_s"):
                v = getattr(c, key)
                if not math.isfinite(v):
                    raise FieldError(f"{where}.{key}", f"not a finite number of seconds ({v})")
            if not 0 <= c.start_s < c.end_s:
                raise FieldError(where, f"need 0 ≤ start_s < end_s, got {c.start_s}..{c.end_s}")
            kind = c.WhichOneof("requirement")
            if kind is None:
                raise FieldError(where, "no requirement (set contact or label)")
            if kind == "contact":
                if c.contact not in CONTACT_NAMES:
                    raise FieldError(f"{where}.contact", f"must be LEFT, RIGHT, BOTH or NONE, got {c.contact}")
                require = {"contact": CONTACT_NAMES[c.contact]}
            else:
                if not c.label:
                    raise FieldError(f"{where}.label", "empty label")
                require = {"label": c.label}
            items.append({"start_s": c.start_s, "end_s": c.end_s, "require": require})
        out.append(items)
    try:
        validate_constraints(out)
    except InputError as exc:
        raise FieldError(field, str(exc)) from None
    return out


# ---------------------------------------------------------------- to the wire


def options_to_proto(
    options: Options | None = None, constraints: list | None = None, recording: Recording | None = None
) -> pb.SynthesisOptions:
    """Options (None: the defaults) → SynthesisOptions, in the named form and the
    deprecated one (module docstring). constraints: sets to send when
    options.constraints is None (a recording's own), else ignored. recording: the
    recording the options go with (`for_recording`)."""
    options = Options() if options is None else options
    if recording is not None:
        options = for_recording(options, recording)
    strategy = get(options.strategy)
    own = strategy.to_wire(strategy.own(options))
    w = options.weights
    msg = pb.SynthesisOptions(
        strategy_name=strategy.name,
        weights=pb.CostWeights(acceleration=w.acc, position=w.position, heading=w.heading, orientation=w.orientation),
    )
    if options.latency_s is not None:
        msg.latency_s = float(options.latency_s)
    msg.heading_from_track = bool(options.heading_from_track)
    msg.rest_heading_deg = float(options.rest_heading_deg)
    msg.speed_threshold_m_s = float(options.speed_threshold)
    msg.strategy_settings.update(values_of(own))
    msg.shared_settings.update(values_of(options.shared))
    # The deprecated form, from the same values.
    enum = strategy_enum_value(strategy.name)
    if enum is not None:
        msg.strategy = enum
    for key, (name, option) in _flat_aliases().items():
        if name == strategy.name and getattr(own, option) is not None:
            setattr(msg, key, getattr(own, option))
    if strategy.name in _legacy_names():
        _fill_legacy(getattr(msg, strategy.name), options, own)
    sets = list(options.constraints) if options.constraints is not None else list(constraints or [])
    msg.constraint_sets.extend(constraints_to_proto(sets))
    return msg


def _fill_legacy(legacy, options: Options, own) -> None:
    """A strategy's deprecated message filled, field by field, from the values it names."""
    legacy.SetInParent()
    shared = values_of(options.shared)
    specs = {s.name for s in option_specs(type(own))}
    negations = _negations(type(own))
    for fd in legacy.DESCRIPTOR.fields:
        if fd.name in COMMON:
            value = getattr(options, COMMON[fd.name])
        elif fd.name in shared:
            value = shared[fd.name]
        elif fd.name in specs:
            value = getattr(own, fd.name)
        elif fd.name in negations:
            value = not getattr(own, negations[fd.name])
        else:
            continue
        if value is None:
            continue
        try:
            if fd.is_repeated:
                getattr(legacy, fd.name).extend(value)
            else:
                setattr(legacy, fd.name, value)
        except (TypeError, ValueError):  # (a value the old message cannot hold: the named form carries it)
            legacy.ClearField(fd.name)


def for_recording(options: Options, rec: Recording) -> Options:
    """The options as the library would read them with `rec` (client side): what the
    recording's provenance decides does not cross the wire (the strategy's
    `options_for_recording`)."""
    return get(options.strategy).options_for_recording(options, rec)


# ---------------------------------------------------------------- from the wire


def options_from_proto(msg: pb.SynthesisOptions, field: str = "options") -> Options:
    """Options from a SynthesisOptions, every value checked (FieldError naming its path).
    An unknown strategy is a FieldError; one specified but not built raises
    StrategyNotImplementedError (UNIMPLEMENTED)."""
    name = msg.strategy_name or strategy_from_enum(msg.strategy, f"{field}.strategy") or DEFAULT
    try:
        get(name)
    except InputError as exc:
        raise FieldError(f"{field}.strategy_name" if msg.strategy_name else f"{field}.strategy", str(exc)) from None
    named = bool(msg.strategy_name) or msg.HasField("strategy_settings")
    which = None if named else msg.WhichOneof(ONEOF)
    legacy = getattr(msg, which) if which else None
    weights = _weights(msg, field)
    latency = None
    if msg.HasField("latency_s"):
        latency = msg.latency_s
        if not (math.isfinite(latency) and latency >= 0):
            raise FieldError(f"{field}.latency_s", f"must be a finite number of seconds ≥ 0, got {latency}")
    # What every strategy reads: from an old client's message that carries it
    # (ViterbiOptions), else the flat fields.
    carries = legacy is not None and any(f.name in COMMON for f in legacy.DESCRIPTOR.fields)
    common = _common(legacy, f"{field}.{which}") if carries else _common(msg, field)
    # The strategy's own options (and, in an old message, shared ones).
    settings, shared_values = {}, {}
    if named:
        where = f"{field}.strategy_settings"
        settings[name] = (struct_values(msg.strategy_settings), where)
    elif legacy is not None:
        own_values, shared_values = _legacy_values(legacy, get(which).options_class, f"{field}.{which}")
        settings[which] = (own_values, f"{field}.{which}")
    else:
        flat = {}
        for key, (owner, option) in _flat_aliases().items():
            if msg.HasField(key):
                flat.setdefault(owner, {})[option] = getattr(msg, key)
        for owner, values in flat.items():
            settings[owner] = (values, field)
    shared_where = (
        f"{field}.shared_settings" if msg.HasField("shared_settings") else (f"{field}.{which}" if which else field)
    )
    if msg.HasField("shared_settings"):
        shared_values = struct_values(msg.shared_settings)
    shared = _checked(SharedOptions, shared_values, shared_where)
    if name not in settings:  # (its defaults: still what the wire allows)
        settings[name] = ({}, f"{field}.{name}" if name in _legacy_names() else f"{field}.strategy_settings")
    own = {}
    for owner, (values, where) in settings.items():
        try:  # before the values are parsed: a client's value never names a file of the server
            get(owner).check_wire(values, owner == name)
        except GraphsvcError as exc:
            raise _field_error(exc, where) from None
        own[owner] = _checked(get(owner).options_class, values, where)
    constraints = constraints_from_proto(msg.constraint_sets, f"{field}.constraint_sets")
    return Options(
        strategy=name,
        weights=weights,
        latency_s=latency,
        constraints=tuple(constraints),
        shared=shared,
        settings=own,
        **common,
    )


def struct_values(struct) -> dict:
    """A Struct's fields as Python values (numbers as floats — NaN and infinities
    kept, for the checks to name —, lists, None for null), without JSON's refusals."""

    def value(v):
        kind = v.WhichOneof("kind")
        if kind == "list_value":
            return [value(x) for x in v.list_value.values]
        if kind == "struct_value":
            return {k: value(x) for k, x in v.struct_value.fields.items()}
        return None if kind in (None, "null_value") else getattr(v, kind)

    return {k: value(v) for k, v in struct.fields.items()}


def _weights(msg: pb.SynthesisOptions, field: str) -> Weights:
    if not msg.HasField("weights"):
        return Weights()
    w = msg.weights
    for key in ("acceleration", "position", "heading", "orientation"):
        v = getattr(w, key)
        if not (math.isfinite(v) and v >= 0):
            raise FieldError(f"{field}.weights.{key}", f"must be a finite number ≥ 0, got {v}")
    return Weights(w.acceleration, w.position, w.heading, w.orientation if w.HasField("orientation") else None)


def _common(src, where: str) -> dict:
    """heading_from_track, rest_heading_deg and speed_threshold from `src` (SynthesisOptions
    or an old ViterbiOptions), checked."""
    if not math.isfinite(src.rest_heading_deg):
        raise FieldError(f"{where}.rest_heading_deg", f"must be finite, got {src.rest_heading_deg}")
    out = {"heading_from_track": bool(src.heading_from_track), "rest_heading_deg": float(src.rest_heading_deg)}
    if src.HasField("speed_threshold_m_s"):
        v = src.speed_threshold_m_s
        if not (math.isfinite(v) and v >= 0):
            raise FieldError(f"{where}.speed_threshold_m_s", f"must be a finite speed ≥ 0, got {v}")
        out["speed_threshold"] = v
    return out


def _legacy_values(legacy, cls, where: str) -> tuple[dict, dict]:
    """(own values, shared values) of a deprecated per-strategy message: every field it
    carries, by name (module docstring)."""
    specs = {s.name for s in option_specs(cls)}
    shared = {s.name for s in option_specs(SharedOptions)}
    negations = _negations(cls)
    own, sh = {}, {}
    for fd, value in legacy.ListFields():
        if fd.name in COMMON:
            continue
        if fd.is_repeated:
            value = list(value)
        if fd.name in shared:
            sh[fd.name] = value
        elif fd.name in specs:
            own[fd.name] = value
        elif fd.name in negations:
            own[negations[fd.name]] = not value
        else:
            raise FieldError(f"{where}.{fd.name}", "is not an option of this strategy")
    return own, sh


def _checked(cls, values: dict, where: str):
    """`from_values` of `cls`, a refusal as a FieldError under `where`."""
    try:
        return from_values(cls, values)
    except GraphsvcError as exc:
        raise _field_error(exc, where) from None


def _field_error(exc: GraphsvcError, where: str) -> FieldError:
    name = getattr(exc, "field", None) or getattr(exc, "option_field", None)
    return FieldError(f"{where}.{name}" if name else where, str(exc))


# ---------------------------------------------------------------- a performer's proportions


def performer_to_proto(height_m: float | None = None, segments_m: dict | None = None) -> pb.Performer:
    """A `Performer` of a height in metres or of segment lengths {name: metres} (one of
    the two)."""
    if (height_m is None) == (segments_m is None):
        raise InputError("a performer is a height or segment lengths, one of the two")
    if height_m is not None:
        return pb.Performer(height_m=float(height_m))
    return pb.Performer(segments=pb.PerformerSegments(segments_m={str(k): float(v) for k, v in segments_m.items()}))


def performer_from_proto(msg: pb.Performer, skeleton, mapping=None, field: str = "performer") -> dict[str, float]:
    """Every segment's length in metres on `skeleton` (the graph's, with its joint map or
    `mapping`) for a `Performer` (`motion.proportions`); FieldError naming the field for
    a height out of range, an unknown segment, a bad length or neither given."""
    from graphsvc.motion.proportions import complete_lengths, lengths_for_height, segment_lengths

    kind = msg.WhichOneof("proportions")
    if kind is None:
        raise FieldError(field, "give height_m or segments")
    kb = segment_lengths(skeleton, mapping)
    where = f"{field}.height_m" if kind == "height_m" else f"{field}.segments.segments_m"
    try:
        if kind == "height_m":
            return lengths_for_height(kb, msg.height_m)
        return complete_lengths(kb, dict(msg.segments.segments_m), "segments")
    except InputError as exc:
        raise FieldError(where, str(exc)) from None
