"""The SSG strategy's own options (Tautges 2012, ch. 4), declared once with
`options.option()`: flags, checks, the gRPC form and the report's settings are derived
from them; and the marker set an option names (`parse_marker_set`)."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace

from graphsvc.errors import GraphsvcError, InputError
from graphsvc.sensors.markers import MarkerSet, keep_markers, load_marker_set, marker_set_from_dict
from graphsvc.strategies.options import OptionError, on_field, option

OFFSETS = ("auto", "fit", "nominal")


def parse_marker_set(text: str) -> MarkerSet:
    """A marker set from an option: a built-in name, a file, or a set as JSON text."""
    text = text.strip()
    if text.startswith("{"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"marker set JSON does not parse: {exc.msg}") from None
        return marker_set_from_dict(data, "marker set")
    return load_marker_set(text)


@dataclass(frozen=True)
class SsgOptions:
    """markers: the marker set — a built-in name (hands-feet, left-foot, head-back,
    vicon), a JSON/TOML file, or a set as JSON text (None: the one the recording names,
    as `simulate --markers` writes); keep: the markers to use (None: every marker of the
    set the recording has); window_s, overlap_s: a window's length and consecutive
    windows' overlap (thesis: N = 20 and o = 10 frames at 60 Hz, 0.33 s and 0.17 s; 15
    and 6, 0.25 s and 0.1 s, for markers on the head and trunk only — None picks by the
    kept markers); k: subsequences a window (8; 16 for head and trunk); weight: the
    transition costs' weight against the node costs (1; 4 for head and trunk, whose
    windows say less of the limbs: the thesis raises it there); offsets: the markers'
    offsets on their segments — "nominal" (the set's), "fit" (estimated from the input
    against the knowledge-base poses it is matched to, `strategies.ssg.offsets`),
    "auto" (fit unless the recording was simulated by graphsvc with this set)."""

    markers: str | None = option(
        None,
        aliases=("--markers",),
        metavar="SET",
        label="SSG markers",
        noun="a marker set's name, file or JSON text",
        help="marker set: hands-feet, left-foot, head-back, vicon, or a marker set file "
        "(JSON/TOML) (default: the one the recording names)",
    )
    keep: tuple[str, ...] | None = option(
        None,
        aliases=("--keep",),
        metavar="NAMES",
        label="SSG keep",
        noun="marker names",
        help="use only these markers of the set (comma-separated; default: all)",
    )
    window_s: float | None = option(
        None,
        low=0.0,
        low_open=True,
        aliases=("--ssg-window",),
        metavar="S",
        label="SSG window",
        noun="a finite number of seconds",
        help="window length, seconds (default 1/3; 0.25 when every marker is on the head or trunk)",
    )
    overlap_s: float | None = option(
        None,
        low=0.0,
        aliases=("--ssg-overlap",),
        metavar="S",
        label="SSG overlap",
        noun="a finite number of seconds",
        help="overlap of consecutive windows, seconds, at most half a window (default 1/6; 0.1)",
    )
    k: int | None = option(
        None, low=1, high=256, metavar="K", label="SSG k", help="subsequences kept a window (default 8; 16)"
    )
    weight: float | None = option(
        None,
        low=0.0,
        metavar="W",
        label="SSG weight",
        help="weight of the transition costs against the node costs (default 1; 4)",
    )
    offsets: str = option(
        "auto",
        choices=OFFSETS,
        label="SSG offsets",
        help="marker offsets on their segments: the set's (nominal), fitted to the input (fit), or fit "
        "unless the recording was simulated (auto, the default)",
    )

    def check(self) -> None:
        if self.window_s is not None and self.overlap_s is not None and self.overlap_s > 0.5 * self.window_s:
            raise OptionError(
                "overlap_s", f"SSG overlap ({self.overlap_s:g} s) must be at most half the window ({self.window_s:g} s)"
            )
        if self.markers is not None:
            try:
                marker_set = parse_marker_set(self.markers)
            except GraphsvcError as exc:
                raise on_field(exc, "markers") from None
            try:
                keep_markers(marker_set, self.keep)
            except GraphsvcError as exc:
                raise on_field(exc, "keep") from None

    def resolved(self, trunk_only: bool) -> SsgOptions:
        """The defaults filled in for a set whose kept markers are (not) all on the head
        and trunk."""
        d = (0.25, 0.1, 16, 4.0) if trunk_only else (1.0 / 3.0, 1.0 / 6.0, 8, 1.0)
        pick = lambda v, default: default if v is None else v  # noqa: E731
        return replace(
            self,
            window_s=pick(self.window_s, d[0]),
            overlap_s=pick(self.overlap_s, d[1]),
            k=pick(self.k, d[2]),
            weight=pick(self.weight, d[3]),
        )
