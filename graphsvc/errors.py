"""Exception types. Every error a user can cause derives from GraphsvcError.

The CLI catches GraphsvcError, prints its message on one line and exits 2; anything
else is a bug and keeps its traceback.
"""

from __future__ import annotations


class GraphsvcError(Exception):
    """Base class of all errors caused by bad input or bad use."""


class FormatError(GraphsvcError):
    """A file is malformed: names the file, the line (when known) and what was expected."""

    def __init__(self, path, message: str, line: int | None = None):
        self.path = str(path)
        self.line = line
        self.detail = message
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


class MissingFileError(FormatError):
    """An input file that is not there: `<path>: no such file`, after what it was for
    when given (`actor map: <path>: no such file`). The one wording for every reader."""

    def __init__(self, path, what: str = ""):
        super().__init__(path, "no such file")
        if what:
            self.args = (f"{what}: {self.args[0]}",)


class UnknownFormatError(GraphsvcError):
    """A path whose format graphsvc does not read."""


class InputError(GraphsvcError):
    """Values are unusable: NaN or infinite, zero frames, shapes that disagree."""


class FieldError(InputError):
    """A request field with an unusable value. field: its path in the request
    (`options.ssg.overlap_s`); message: what is wrong with it."""

    def __init__(self, field: str, message: str):
        self.field = field
        self.detail = message
        super().__init__(f"{field}: {message}")


class CalibrationQualityError(InputError):
    """A mounting calibration was made but is not to be trusted (a sensor that matched
    the motion badly, moved during the pose, or whose two views of gravity disagree):
    the message names them in one line; calibration: the CAL document all the same."""

    def __init__(self, message: str, calibration: dict):
        self.calibration = calibration
        super().__init__(message)


class SkeletonError(GraphsvcError):
    """A skeleton lacks joints a layout, mapping or operation needs."""


class LayoutError(GraphsvcError):
    """A sensor layout is unknown or malformed."""


class StrategyNotImplementedError(GraphsvcError):
    """A search strategy that is specified (OLNG, SSG) but not built yet."""


class SearchCancelled(GraphsvcError):
    """The caller asked a running search to stop (e.g. its client went away)."""
