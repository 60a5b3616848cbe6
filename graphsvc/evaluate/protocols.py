"""Hold-out protocols: what a test clip hides from the graph it is searched in.

Leave-one-out evaluation scores a reconstruction of a clip whose data the search may
not use. How much else it hides decides how close the figures come to a new performer:

- `clip`: the test clip's performance (the take and its mirrored or reversed copies).
- `takes` (the default): every take of the test clip's content × style: the clips whose
  names agree but for a take number of three or more digits at the end
  (`dataset-2_walk_normal_004`: Bandai-Namco's `dataset-N_<content>_<style>_<take>`,
  or any knowledge base named so); a clip named otherwise has no takes but itself.
  Bandai's takes of one content × style are one actor performing the same thing, so
  hiding only the clip leaves three near-twins searchable.
- `actor`: every clip of the test clip's performer (`actor_groups`).
- `content`: every clip with the test clip's content label; label accuracy is then
  not applicable.

What a hidden clip hides in the graph (its performance, its interpolated segments and
bridges) is `graph.holdout`'s.

Actors (`actor_groups`): clips are joined into one actor when an actor map names them
alike (a JSON file `{"clip name or glob": "actor", ...}`), when a built-in rule does
(Bandai-Namco dataset 2: the styles active, elderly and exhausted are one actor,
feminine and youthful another, masculine and normal the third; CMU: the subject, the
part of `SS_TT` before the underscore), or when their skeletons' offsets are equal
(one person's calibration). `check_actor_map` reports where the built-in and given
maps disagree with the offsets.
"""

from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass

import numpy as np

from graphsvc.errors import InputError
from graphsvc.fileio import read_json_file
from graphsvc.graph.holdout import performance_key
from graphsvc.graph.model import MotionGraph

PROTOCOLS = ("clip", "takes", "actor", "content")
DEFAULT_PROTOCOL = "takes"

_TAKE = re.compile(r"^(?P<stem>.*[A-Za-z].*)_(?P<take>\d{3,})$")
_BANDAI = re.compile(r"^dataset-(?P<set>\d+)_(?P<content>[^_]+)_(?P<style>[^_]+)_(?P<take>\d+)$")
_CMU = re.compile(r"^(?P<subject>\d+)_(?P<trial>\d+)$")
BANDAI_DATASET2_ACTORS = {
    "active": "bandai-2:active/elderly/exhausted",
    "elderly": "bandai-2:active/elderly/exhausted",
    "exhausted": "bandai-2:active/elderly/exhausted",
    "feminine": "bandai-2:feminine/youthful",
    "youthful": "bandai-2:feminine/youthful",
    "masculine": "bandai-2:masculine/normal",
    "normal": "bandai-2:masculine/normal",
}


@dataclass(frozen=True)
class Clip:
    """What a protocol reads of a clip: its name (no extension, no augmentation
    suffix), content label, and skeleton offsets when known ((J, 3), or None)."""

    name: str
    label: str
    offsets: np.ndarray | None = None


def take_key(name: str) -> str:
    """The name without its take number (`walk_normal_004` → `walk_normal`); a name
    without one (two digits, as the procedural `walk_01`, or a rest without letters,
    as CMU's `02_05`) is its own key."""
    m = _TAKE.match(name)
    return m.group("stem") if m else name


def builtin_actor(name: str) -> str | None:
    """The actor a built-in rule gives a clip name, or None."""
    m = _BANDAI.match(name)
    if m and m.group("set") == "2" and m.group("style") in BANDAI_DATASET2_ACTORS:
        return BANDAI_DATASET2_ACTORS[m.group("style")]
    m = _CMU.match(name)
    if m:
        return f"cmu:{m.group('subject')}"
    return None


def load_actor_map(path) -> dict[str, str]:
    """An actor map file: a JSON object from clip names or globs to actor names."""
    data = read_json_file(path, "actor map")
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise InputError(f"actor map {path}: want an object of clip name or glob → actor name")
    return data


def _mapped_actor(name: str, actor_map: dict[str, str] | None) -> str | None:
    if not actor_map:
        return None
    if name in actor_map:
        return actor_map[name]
    for pattern, actor in actor_map.items():
        if fnmatch.fnmatchcase(name, pattern):
            return actor
    return None


def _offsets_key(offsets) -> bytes | None:
    return None if offsets is None else np.round(np.asarray(offsets, dtype=np.float64), 4).tobytes()


def actor_groups(clips: list[Clip], actor_map: dict[str, str] | None = None) -> np.ndarray:
    """(C,) int: each clip's actor, numbered in order of first appearance. Clips are
    one actor when the actor map (else the built-in rule) names them alike or their
    offsets are equal; a clip nothing links is an actor of its own."""
    parent = list(range(len(clips)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def join(a: int, b: int) -> None:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)

    first: dict = {}
    for i, c in enumerate(clips):
        named = _mapped_actor(c.name, actor_map) or builtin_actor(c.name)
        for key in (("name", named) if named else None, ("offsets", _offsets_key(c.offsets))):
            if key is None or key[1] is None:
                continue
            if key in first:
                join(first[key], i)
            else:
                first[key] = i
    roots = [root(i) for i in range(len(clips))]
    order = {r: k for k, r in enumerate(dict.fromkeys(roots))}
    return np.array([order[r] for r in roots], dtype=np.int64)


def check_actor_map(clips: list[Clip], actor_map: dict[str, str] | None = None) -> list[str]:
    """Where names and offsets disagree: one line for each named actor whose clips have
    different offsets, and for each offset group named as several actors."""
    by_name: dict = {}
    by_offsets: dict = {}
    for c in clips:
        named = _mapped_actor(c.name, actor_map) or builtin_actor(c.name)
        key = _offsets_key(c.offsets)
        if named is None or key is None:
            continue
        by_name.setdefault(named, set()).add(key)
        by_offsets.setdefault(key, set()).add(named)
    out = [
        f"actor {name!r}: its clips have {len(keys)} different skeletons"
        for name, keys in by_name.items()
        if len(keys) > 1
    ]
    out += [
        f"one skeleton is named as {len(names)} actors: {', '.join(sorted(names))}"
        for names in by_offsets.values()
        if len(names) > 1
    ]
    return out


def graph_clips(graph: MotionGraph, offsets: dict[int, np.ndarray] | None = None) -> list[Clip]:
    """The protocol view of a graph's clips (augmented copies under their original's
    name); offsets: graph clip index → skeleton offsets, where known."""
    out = []
    for k, c in enumerate(graph.clips):
        name = performance_key(c.get("source", ""), c["name"])[1]
        label = str(c.get("label") or (c.get("labels") or [""])[0] or "")
        out.append(Clip(name, label, None if offsets is None else offsets.get(k)))
    return out


def hidden_clips(
    protocol: str, test: Clip, clips: list[Clip], actors: np.ndarray | None = None, test_actor: int | None = None
) -> list[int]:
    """Indices into `clips` (a graph's, `graph_clips`) that `test` hides under
    `protocol`. The test clip itself, if among them, is found by name. actors /
    test_actor: `actor_groups` over clips (and the test clip's group), for `actor`."""
    if protocol not in PROTOCOLS:
        raise InputError(f"unknown hold-out protocol {protocol!r} (choose from {', '.join(PROTOCOLS)})")
    if protocol == "clip":
        return [k for k, c in enumerate(clips) if c.name == test.name]
    if protocol == "takes":
        key = take_key(test.name)
        return [k for k, c in enumerate(clips) if c.name == test.name or take_key(c.name) == key]
    if protocol == "content":
        return [k for k, c in enumerate(clips) if c.name == test.name or (test.label and c.label == test.label)]
    if actors is None or test_actor is None:
        raise InputError("the actor protocol needs every clip's actor")
    return [k for k, c in enumerate(clips) if c.name == test.name or actors[k] == test_actor]


def hide_lists(
    graph: MotionGraph, tests: list, protocol: str, offsets: dict | None = None, actor_map: dict[str, str] | None = None
) -> list[list[int]]:
    """For each test clip (Motions), the graph clip indices it hides under `protocol`
    (`hidden_clips`; a test clip absent from the graph hides what the graph holds of
    its set). offsets: graph clip index → skeleton offsets where known (the actor
    protocol links equal skeletons; the test clips' own are always used)."""
    clips = graph_clips(graph, offsets)
    wanted = [
        Clip(performance_key(m.source, m.name)[1], str(m.labels[0]) if m.labels else "", np.asarray(m.skeleton.offsets))
        for m in tests
    ]
    actors = test_actors = None
    if protocol == "actor":
        groups = actor_groups(clips + wanted, actor_map)
        actors, test_actors = groups[: len(clips)], groups[len(clips) :]
    out = []
    for i, c in enumerate(wanted):
        hide = hidden_clips(protocol, c, clips, actors, None if test_actors is None else int(test_actors[i]))
        if clips and len(hide) == len(clips):
            raise InputError(
                f"--hold-out {protocol}: {c.name} hides every clip of the graph, leaving nothing to "
                "search (choose a protocol that hides less)"
            )
        out.append(hide)
    return out


# Content labels of locomotion (a word of the label); every other label is a gesture
# performed standing. Reports give both groups apart as well as together.
LOCOMOTION_WORDS = ("walk", "run", "dash", "jog", "stop", "step", "jump")


def activity(label: str) -> str:
    """ "locomotion" or "gestures" for a content label (`LOCOMOTION_WORDS`)."""
    words = re.split(r"[^a-z]+", str(label).lower())
    return "locomotion" if any(w in LOCOMOTION_WORDS for w in words) else "gestures"
