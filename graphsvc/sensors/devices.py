"""Real IMU devices in: Xsens MVN exports (MVNX) as recordings, and device name maps
that rename a device's sensors to a graph layout's.

Axes
    A device whose world has +Z up (Xsens: X forward/north, Y left/west, Z up) is
    turned onto graphsvc's world (+Y up, facing +Z, +X the body's left) by the cyclic
    change (x, y, z) → (y, z, x), as for C3D and marker files (`sensors.axes`): the
    device's X (forward) becomes graphsvc's Z, Y (left) X, Z (up) Y. It is the
    rotation Q_Z_UP_TO_Y_UP = (0.5, −0.5, −0.5, −0.5) (w, x, y, z), −120° about
    (1, 1, 1)/√3, and a sensor's orientation becomes q_world = Q_Z_UP_TO_Y_UP ⊗
    q_device (`sensors.axes.z_up_to_y_up`). Readings stay in each sensor's own frame,
    which this does not touch.

MVNX (`read_mvnx`)
    XML from Xsens MVN (MVNX 3 and 4). Sensors are the ``<sensors><sensor label=…>``
    of the first ``<subject>``, in file order; their labels (Xsens segment names:
    Pelvis, T8, Head, RightShoulder, RightUpperArm, RightForeArm, RightHand, …,
    RightUpperLeg, RightLowerLeg, RightFoot, …) are the recording's sensor names.
    Samples are the ``type="normal"`` frames; frames of any other type (identity,
    tpose, tpose-isb, npose) are calibration poses: their types are listed in
    meta["calibration_frames"], and the sensor orientations they carry (if any), in
    graphsvc's world, in meta["poses"][type] (S lists of w, x, y, z). Timestamps are
    the frames' ``time`` (ms from the start of the take, whole milliseconds in Xsens's
    exports), else their ``index`` / frameRate; the rate is the subject's
    ``frameRate``.

    Accelerations (m/s², each sensor's own frame, gravity included, as the device
    measured): ``sensorAcceleration`` where the export has it (already so); else
    ``sensorFreeAcceleration`` (Xsens's global frame, gravity removed) turned back
    into the sensor's frame with ``sensorOrientation`` (the sensor frame's rotation
    into the global frame, w x y z) and gravity added back:
    a_sensor = R⁻¹ · (a_free + (0, 0, 9.81)). Orientations: ``sensorOrientation`` in
    graphsvc's world (Axes above); an all-zero quaternion is missing (NaN).

    meta: source, imported_from "mvnx", sensor_frame "device" (readings in each
    device's own frame; a later calibration step maps them to the layout's frames),
    acceleration (the field used), mvnx_version, mvn_version, frame_rate_hz,
    configuration (e.g. "UpperBody", "FullBody", or None), timestamps_from,
    calibration_frames and, when there are any, poses.

    The file is read as a stream (element by element, each frame's values parsed by
    numpy from its text), so a long take needs memory for its readings only. A file
    that is not well-formed XML (truncated, say), has no sensors, no normal frames or
    values of the wrong count is refused with a FormatError naming the file (and the
    line where the XML parser tells one).

Device maps (`device_map`, `apply_device_map`)
    A JSON object mapping device sensor names to the graph layout's, either bare or
    wrapped: ``{"device": "xsens", "sensors": {"LeftForeArm": "l_forearm", …}}``.
    Applying a map renames the mapped sensors, drops the others (listed in
    meta["unmapped_sensors"]) and orders the result as the map does (or as `order`
    says). Built-in maps (DEVICES), for every layout preset, come from namings that
    say which device sensor sits at each preset sensor's place (NAMINGS): "xsens"
    takes Xsens MVN segment names (Pelvis, T8, LeftForeArm, LeftLowerLeg, …) or MVN
    skeleton names (Hips, Spine3, LeftForeArm, LeftLeg, …), whichever names more of
    the recording's sensors; "mvn" the skeleton names alone; "generic" the names of
    a device CSV (left_wrist, l_knee, pelvis, head, … in the spellings `generic_key`
    folds together). DEVICE_MAPS lists each device's first naming.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import replace
from pathlib import Path
from xml.parsers.expat import errors as expat_errors

import numpy as np

from graphsvc.errors import FormatError, InputError
from graphsvc.fileio import read_input_text, require_file
from graphsvc.motion import quat
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.axes import z_up_to_y_up
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.recording import Recording

CALIBRATION_POSES = ("tpose", "tpose-isb", "npose")  # frames whose sensor orientations meta keeps
_ACCELERATION_FIELDS = ("sensorAcceleration", "sensorFreeAcceleration")
_ORIENTATION_FIELD = "sensorOrientation"
# expat's "no element found" and "unclosed token": the text stopped inside an element.
_XML_ENDS_EARLY = (
    expat_errors.codes[expat_errors.XML_ERROR_NO_ELEMENTS],
    expat_errors.codes[expat_errors.XML_ERROR_UNCLOSED_TOKEN],
)


# ---------------------------------------------------------------- MVNX


class _Rows:
    """A growing (n, width) float64 table: rows appended one at a time, amortised O(1)."""

    def __init__(self, width: int):
        self.data = np.empty((64, width))
        self.n = 0

    def append(self, row: np.ndarray) -> None:
        if self.n == self.data.shape[0]:
            self.data = np.concatenate([self.data, np.empty_like(self.data)])
        self.data[self.n] = row
        self.n += 1

    def array(self) -> np.ndarray:
        return self.data[: self.n]


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


def _values(path: Path, text: str | None, sensors: int, per: int, what: str, where: str) -> np.ndarray:
    """`per` numbers a sensor from an element's whitespace-separated text (FormatError
    if it holds anything else)."""
    try:
        v = np.fromstring(text or "", dtype=np.float64, sep=" ")
    except ValueError:
        raise FormatError(path, f"{where}: {what} holds a value that is not a number") from None
    if v.size != sensors * per:
        raise FormatError(
            path, f"{where}: {what} has {v.size} values, expected {sensors * per} ({per} for each of {sensors} sensors)"
        )
    if np.isinf(v).any():
        raise FormatError(path, f"{where}: {what} holds an infinite value")
    return v


def _positive(value: str | None) -> float | None:
    try:
        x = float(value) if value is not None else math.nan
    except ValueError:
        return None
    return x if math.isfinite(x) and x > 0 else None


def _orientations(path: Path, q: np.ndarray, names: list[str], where: str | None = None) -> np.ndarray:
    """Quaternions read from a file, (S, 4) of one frame (`where`) or (T, S, 4) of the
    normal frames: all-zero → NaN (missing), others normalised; FormatError for one
    that is far from unit length."""
    q = np.array(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1)
    zero = norm < 1e-6
    bad = ~zero & np.isfinite(norm) & (np.abs(norm - 1.0) > 1e-2)
    if bad.any():
        k = tuple(np.argwhere(bad)[0])
        at = where if where is not None else f"normal frame {k[0] + 1}"
        raise FormatError(
            path, f"{at}: the sensorOrientation of {names[k[-1]]} is not a unit quaternion (norm {norm[k]:.4g})"
        )
    q[zero] = np.nan
    return q / np.where(zero, 1.0, norm)[..., None]


def read_mvnx(path) -> Recording:
    """An Xsens MVNX export as a recording (module docstring). FormatError for a file
    that is not a readable MVNX with sensors and normal frames."""
    path = require_file(path)
    reader = _MvnxReader(path)
    with open(path, "rb") as f:
        events = ET.iterparse(f, events=("start", "end"))
        while True:
            try:
                event, elem = next(events)
            except StopIteration:
                break
            except ET.ParseError as exc:
                line = exc.position[0] if exc.position else None
                message = re.sub(r":\s*line \d+, column \d+$", "", str(exc))
                if exc.code in _XML_ENDS_EARLY:
                    message += " (the file ends early: truncated?)"
                raise FormatError(path, f"not a well-formed MVNX (XML) file: {message}", line=line) from None
            except (LookupError, ValueError) as exc:  # the XML declaration's encoding: unknown, or multi-byte
                raise FormatError(path, f"not a readable MVNX (XML) file: {exc}", line=1) from None
            if event == "start":
                reader.start(_local(elem.tag), elem)
            else:
                reader.end(_local(elem.tag), elem)
    return reader.recording()


class _MvnxReader:
    """The state of one MVNX file read element by element (iterparse events): what the
    first <subject> says, its sensors, and its frames' readings as they come."""

    def __init__(self, path: Path):
        self.path = path
        self.stack: list[str] = []  # open elements' local names
        self.subjects = 0
        self.info: dict = {"subject": {}, "frames": {}}
        self.labels: list[str] = []
        self.frames_parent = None
        self.S: int | None = None  # sensors, fixed at the first frame
        self.field: str | None = None  # the acceleration field, fixed at the first normal frame
        self.has_orientation = False
        self.acc = self.q = self.times = None
        self.calibration: list[str] = []
        self.poses: dict[str, list] = {}
        self.ordinal = 0

    def start(self, tag: str, elem) -> None:
        stack = self.stack
        if not stack and tag != "mvnx":
            raise FormatError(self.path, f"not an MVNX file: the root element is <{tag}>, not <mvnx>")
        stack.append(tag)
        if len(stack) == 1:
            self.info["mvnx_version"] = elem.get("version")
        elif len(stack) == 2 and tag == "mvn":
            self.info["mvn_version"] = elem.get("version")
        elif len(stack) == 2 and tag == "subject":
            self.subjects += 1
            if self.subjects == 1:
                self.info["subject"] = dict(elem.attrib)
        elif len(stack) == 3 and tag == "frames" and self.subjects == 1:
            self.frames_parent = elem
            self.info["frames"] = dict(elem.attrib)

    def end(self, tag: str, elem) -> None:
        self.stack.pop()
        first = self.subjects == 1 and self.stack[:2] == ["mvnx", "subject"]
        if first and tag == "sensor" and self.stack[2:] == ["sensors"]:
            self.labels.append((elem.get("label") or "").strip())
        elif tag == "frame":
            if first and self.stack[2:] == ["frames"]:
                self.frame(elem)
            elem.clear()
            parent = self.frames_parent
            if parent is not None and len(parent) and parent[-1] is elem:
                del parent[-1]  # memory stays bounded on a long take

    def frame(self, elem) -> None:
        path = self.path
        self.ordinal += 1
        kind = elem.get("type", "normal")
        index = elem.get("index")
        where = f"frame {self.ordinal} ({kind}{f', index {index}' if index is not None else ''})"
        if self.S is None:
            self.S = _sensor_count(path, self.labels, self.info["frames"])
        S = self.S
        children = {_local(c.tag): c.text for c in elem}
        if kind != "normal":
            self.calibration.append(kind)
            if kind in CALIBRATION_POSES and children.get(_ORIENTATION_FIELD) is not None:
                q = _values(path, children[_ORIENTATION_FIELD], S, 4, _ORIENTATION_FIELD, where)
                q = np.round(z_up_to_y_up(_orientations(path, q.reshape(S, 4), self.labels, where)), 9)
                self.poses[kind] = [None if np.isnan(row).any() else row.tolist() for row in q]
            return
        if self.field is None:
            self.field = next((name for name in _ACCELERATION_FIELDS if name in children), None)
            if self.field is None:
                raise FormatError(
                    path, f"{where}: no sensor accelerations (neither {' nor '.join(_ACCELERATION_FIELDS)})"
                )
            self.has_orientation = _ORIENTATION_FIELD in children
            if self.field == "sensorFreeAcceleration" and not self.has_orientation:
                raise FormatError(
                    path,
                    f"{where}: sensorFreeAcceleration (global frame) needs "
                    f"{_ORIENTATION_FIELD} to turn it into each sensor's frame",
                )
            self.acc, self.q, self.times = _Rows(3 * S), _Rows(4 * S), _Rows(2)
        for name in (self.field, _ORIENTATION_FIELD) if self.has_orientation else (self.field,):
            if name not in children:
                raise FormatError(path, f"{where}: lacks {name}")
        self.acc.append(_values(path, children[self.field], S, 3, self.field, where))
        if self.has_orientation:
            self.q.append(_values(path, children[_ORIENTATION_FIELD], S, 4, _ORIENTATION_FIELD, where))
        self.times.append([_number(elem.get("time")), _number(index)])

    def recording(self) -> Recording:
        path = self.path
        if self.subjects == 0:
            raise FormatError(path, "holds no <subject>")
        S = self.S if self.S is not None else _sensor_count(path, self.labels, self.info["frames"])
        if self.field is None:
            raise FormatError(
                path,
                "holds no normal frames (samples)"
                + (f", only calibration frames ({', '.join(self.calibration)})" if self.calibration else ""),
            )
        subject = self.info["subject"]
        times = self.times.array()
        T = times.shape[0]
        rate = _positive(subject.get("frameRate"))
        if np.isfinite(times[:, 0]).all():
            t, source = times[:, 0] / 1000.0, "time"
        elif rate is not None and np.isfinite(times[:, 1]).all():
            t, source = times[:, 1] / rate, "index"
        elif rate is not None:
            t, source = np.arange(T) / rate, "order"
        else:
            raise FormatError(path, "neither the subject's frameRate nor the frames' times tell the sample rate")
        bad = np.diff(t) <= 0
        if bad.any():
            k = int(np.argmax(bad)) + 1
            raise FormatError(
                path,
                f"normal frame {k + 1}: its {source} ({t[k]:g} s) does not follow the previous one's ({t[k - 1]:g} s)",
            )
        if rate is None:
            if T < 2:
                raise FormatError(path, "no frameRate, and one frame: cannot tell the sample rate")
            rate = 1.0 / float(np.median(np.diff(t)))

        readings = self.acc.array().reshape(T, S, 3)
        orientations = None
        if self.has_orientation:
            q_device = _orientations(path, self.q.array().reshape(T, S, 4), self.labels)
            orientations = z_up_to_y_up(q_device).astype(np.float32)
            if self.field == "sensorFreeAcceleration":
                readings = quat.inv_rotate(q_device, readings + np.array([0.0, 0.0, GRAVITY]))
        meta = {
            "source": str(path),
            "imported_from": "mvnx",
            "sensor_frame": "device",
            "acceleration": self.field,
            "mvnx_version": self.info.get("mvnx_version"),
            "mvn_version": self.info.get("mvn_version"),
            "frame_rate_hz": float(rate),
            "configuration": subject.get("configuration"),
            "timestamps_from": source,
            "calibration_frames": self.calibration,
        }
        if self.poses:
            meta["poses"] = self.poses
        if self.subjects > 1:
            meta["subjects"] = self.subjects  # only the first is read
        rec = Recording(
            rate_hz=float(rate),
            timestamps_s=np.ascontiguousarray(t, dtype=np.float64),
            sensor_names=tuple(self.labels),
            accelerations=readings.astype(np.float32),
            orientations=orientations,
            meta=meta,
        )
        try:
            rec.validate()
        except InputError as exc:
            raise FormatError(path, f"not a usable recording: {exc}") from None
        return rec


def _number(text: str | None) -> float:
    try:
        return float(text) if text is not None else math.nan
    except ValueError:
        return math.nan


def _sensor_count(path: Path, labels: list[str], frames_attrib: dict) -> int:
    """The number of sensors, checked: at least one, labelled, unique, and as many as
    the <frames sensorCount=…> says when it says."""
    if not labels:
        raise FormatError(path, "holds no sensors (no <sensors><sensor label=…> before the frames)")
    if any(not n or set(n) & set(',"\r\n') for n in labels):
        raise FormatError(path, f"bad sensor label among {', '.join(map(repr, labels))}")
    dup = sorted(n for n, c in Counter(labels).items() if c > 1)
    if dup:
        raise FormatError(path, f"duplicate sensor labels: {', '.join(dup)}")
    declared = frames_attrib.get("sensorCount")
    if declared is not None and declared.strip() != str(len(labels)):
        raise FormatError(path, f'<frames sensorCount="{declared}"> but {len(labels)} sensors are listed')
    return len(labels)


# ---------------------------------------------------------------- device maps


def generic_key(name: str) -> str:
    """A sensor name as the generic naming compares it: lower case, letters and digits
    only, the side as a leading l or r (`left_wrist`, `LeftWrist`, `wrist_L`, `l-wrist`
    → `lwrist`)."""
    lowered = name.strip().lower()
    m = re.fullmatch(r"(.*?)[\W_]+([lr])", lowered)  # a side after a separator: wrist_l
    if m:
        lowered = m.group(2) + m.group(1)
    key = re.sub(r"[\W_]+", "", lowered)
    for word, side in (("left", "l"), ("right", "r")):
        if key.startswith(word):
            return side + key[len(word) :]
        if key.endswith(word):
            return side + key[: -len(word)]
    return key


def _names(entry) -> tuple[str, ...]:
    return (entry,) if isinstance(entry, str) else tuple(entry)


def _naming_map(naming: dict, places: dict[str, str], present, loose: bool = False) -> dict[str, str]:
    """{device name: layout sensor} of one naming for a layout's `places`: each sensor
    takes the first of its place's names among `present` (the recording's, compared by
    `generic_key` when loose, else exactly; None: the first name), each device sensor
    at most once."""
    out: dict[str, str] = {}
    if present is None:
        by_key = None
    else:
        by_key = {}
        for n in present:
            by_key.setdefault(generic_key(n), n)
    for sensor, place in places.items():
        if place not in naming:
            continue
        for candidate in _names(naming[place]):
            name = (
                candidate
                if by_key is None
                else by_key.get(generic_key(candidate))
                if loose
                else candidate
                if candidate in present
                else None
            )
            if name is not None and name not in out:
                out[name] = sensor
                break
    return out


# Built-in namings. A preset's sensors are named after where they sit (`l_wrist`: the
# forearm near the wrist, `l_forearm`: its middle, `l_knee`, `l_shin`, `l_ankle`: the
# shin below the knee, in its middle, above the ankle, `lower_back`, `pelvis`, `chest`,
# `head`); a naming says which device sensor sits there. Xsens straps one sensor a
# segment: its forearm sensor serves every forearm place, its lower-leg one every shin
# place. Xsens names a sensor by its segment in MVN ("segments": Pelvis, L5, L3, T12,
# T8, Neck, Head, RightShoulder, RightUpperArm, RightForeArm, RightHand, RightUpperLeg,
# RightLowerLeg, RightFoot, …) or by the MVN skeleton's joint, as in its BVH exports
# ("skeleton": Hips, Spine, Spine1, Spine2, Spine3, Neck, Head, RightShoulder,
# RightArm, RightForeArm, RightHand, RightUpLeg, RightLeg, RightFoot, …).
_XSENS_PLACES = {"wrist": "ForeArm", "forearm": "ForeArm", "knee": "LowerLeg", "shin": "LowerLeg", "ankle": "LowerLeg"}
_MVN_PLACES = {"wrist": "ForeArm", "forearm": "ForeArm", "knee": "Leg", "shin": "Leg", "ankle": "Leg"}
_SIDES = {"l_": "Left", "r_": "Right"}


def _xsens_naming(places: dict[str, str], trunk: dict[str, str]) -> dict[str, str]:
    """{place: device name} of an Xsens naming: the limbs' places on both sides, then the trunk's."""
    limbs = {prefix + place: side + part for prefix, side in _SIDES.items() for place, part in places.items()}
    return {**limbs, **trunk}


XSENS_SEGMENTS = _xsens_naming(
    _XSENS_PLACES, {"pelvis": "Pelvis", "lower_back": "Pelvis", "chest": "T8", "head": "Head"}
)
MVN_SKELETON = _xsens_naming(_MVN_PLACES, {"pelvis": "Hips", "lower_back": "Hips", "chest": "Spine3", "head": "Head"})

# The generic naming: per place, the names a device CSV may give it, most specific
# first, compared by `generic_key` (case, separators and the side's spelling aside:
# left_wrist, LeftWrist, l-wrist, lwrist and wrist_l are one name).
_GENERIC_LIMBS = {
    "wrist": ("wrist", "forearm", "lower_arm"),
    "forearm": ("forearm", "lower_arm", "wrist"),
    "knee": ("knee", "shin", "lower_leg"),
    "shin": ("shin", "lower_leg", "knee", "ankle"),
    "ankle": ("ankle", "shin", "lower_leg"),
}
GENERIC = {
    **{
        prefix + place: tuple(f"{side.lower()}_{n}" for n in names)
        for prefix, side in _SIDES.items()
        for place, names in _GENERIC_LIMBS.items()
    },
    "pelvis": ("pelvis", "hips", "hip", "waist", "sacrum", "root", "lower_back"),
    "lower_back": ("lower_back", "pelvis", "hips", "waist", "sacrum", "back"),
    "chest": ("chest", "sternum", "upper_back", "thorax", "torso"),
    "head": ("head", "forehead"),
}

# device → its namings ({place: device name or names}, tried in turn).
NAMINGS: dict[str, tuple[dict, ...]] = {
    "xsens": (XSENS_SEGMENTS, MVN_SKELETON),
    "mvn": (MVN_SKELETON,),
    "generic": (GENERIC,),
}
DEVICES = tuple(NAMINGS)  # the built-in maps, as `--device-map` names them

# The places of each preset's sensors (a preset's sensor names are places).
PLACES: dict[str, dict[str, str]] = {name: {s: s for s in layout.sensor_names} for name, layout in PRESETS.items()}

# Built-in maps: device → layout preset → {device sensor name: layout sensor name}, in
# the layout's order, each device's first naming (generic: each place's first name).
DEVICE_MAPS: dict[str, dict[str, dict[str, str]]] = {
    device: {layout: _naming_map(namings[0], places, None) for layout, places in PLACES.items()}
    for device, namings in NAMINGS.items()
}


def _short(names, most: int = 6) -> str:
    names = list(names)
    return ", ".join(names[:most]) + (" …" if len(names) > most else "") if names else "it has none"


def device_map(name_or_path: str, layout_name: str | None, present=None) -> dict[str, str]:
    """A device map: a built-in device (DEVICES) for the layout preset `layout_name`, or
    a JSON map file (module docstring). present: the recording's sensor names, which
    choose among a device's namings (the one that maps more of them; xsens: MVN segment
    or skeleton names) and pick the generic naming's spelling; None: the first naming
    as DEVICE_MAPS has it. InputError for a built-in device and a layout that is not a
    preset, a built-in map that names none of `present`, or a name that is neither;
    FormatError for a malformed file."""
    if name_or_path in NAMINGS:
        if layout_name not in PLACES:
            raise InputError(
                f"no built-in {name_or_path} map for layout {layout_name!r} (it has maps for "
                f"{', '.join(PLACES)}); give a map file instead"
            )
        if present is None:
            return dict(DEVICE_MAPS[name_or_path][layout_name])
        present = tuple(present)
        maps = [_naming_map(n, PLACES[layout_name], present, loose=n is GENERIC) for n in NAMINGS[name_or_path]]
        best = max(maps, key=len)  # (the first of equals)
        if not best:
            raise InputError(
                f"the {name_or_path} device map names none of the recording's sensors "
                f"({_short(present)}) for layout {layout_name!r} (it takes "
                f"{_short(DEVICE_MAPS[name_or_path][layout_name])})"
            )
        return best
    path = Path(name_or_path)
    if not path.is_file():
        raise InputError(
            f"unknown device map {name_or_path!r}: not a built-in device ({', '.join(DEVICES)}) and no such file"
        )
    return load_device_map(path)


def unmapped_note(mapped: Recording, sensor_names, device: str) -> str | None:
    """One line naming the layout's sensors (`sensor_names`) that the device map
    `device` left without a device sensor, or None when it found them all."""
    missing = [n for n in sensor_names if n not in mapped.sensor_names]
    if not missing:
        return None
    device_names = mapped.meta.get("unmapped_sensors", [])
    return (
        f"device map {device}: no sensor of the recording for {', '.join(missing)} (unmapped: "
        f"{', '.join(device_names) or 'none'})"
    )


def load_device_map(path) -> dict[str, str]:
    """A device map file: {"device": ..., "sensors": {device name: layout name}} or
    just the object of names. FormatError for anything else, a name given twice on
    either side, or an empty map."""
    path = Path(path)

    def pairs(items):
        keys = [k for k, _ in items]
        dup = sorted(k for k, c in Counter(keys).items() if c > 1)
        if dup:
            raise FormatError(path, f"names {', '.join(map(repr, dup))} more than once")
        return dict(items)

    text = read_input_text(path, "device map", encoding="utf-8-sig")
    try:
        data = json.loads(text, object_pairs_hook=pairs)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"not valid JSON: {exc.msg}", line=exc.lineno) from None
    if isinstance(data, dict) and isinstance(data.get("sensors"), dict):
        unknown = sorted(set(data) - {"device", "sensors"})
        if unknown:
            raise FormatError(path, f"unknown keys {', '.join(unknown)} (a map has device and sensors)")
        data = data["sensors"]
    try:
        return check_device_map(data)
    except InputError as exc:
        raise FormatError(path, str(exc)) from None


def check_device_map(mapping) -> dict[str, str]:
    """`mapping` as a {device name: layout name} dict, checked: non-empty, names
    non-empty strings, no layout name given twice. InputError otherwise."""
    if not isinstance(mapping, dict) or not mapping:
        raise InputError('a device map must be a non-empty object {"device sensor": "layout sensor", ...}')
    for k, v in mapping.items():
        if not isinstance(k, str) or not isinstance(v, str) or not k.strip() or not v.strip():
            raise InputError(f"device map entry {k!r}: {v!r}: names must be non-empty strings")
    dup = sorted(v for v, c in Counter(mapping.values()).items() if c > 1)
    if dup:
        raise InputError(f"the device map names layout sensor(s) {', '.join(dup)} more than once")
    return dict(mapping)


def apply_device_map(rec: Recording, mapping: dict, order=None) -> Recording:
    """`rec` with its sensors renamed by `mapping` ({device name: layout name}), the
    unmapped ones dropped and listed in meta["unmapped_sensors"]. The sensors come in
    the map's order, or with `order`'s names (e.g. a graph's sensors) first, in that
    order. InputError for a bad map or one that names none of the recording's
    sensors."""
    mapping = check_device_map(mapping)
    present = [k for k in mapping if k in rec.sensor_names]
    if not present:
        raise InputError(
            f"the device map names none of the recording's sensors ({', '.join(rec.sensor_names) or 'it has none'})"
        )
    if order is not None:
        rank = {n: i for i, n in enumerate(order)}
        present.sort(key=lambda k: rank.get(mapping[k], len(rank)))  # stable: the map's order after
    cols = [rec.sensor_names.index(k) for k in present]
    meta = dict(rec.meta)
    meta["unmapped_sensors"] = [n for n in rec.sensor_names if n not in mapping]
    meta["device_sensors"] = {mapping[k]: k for k in present}
    out = replace(
        rec,
        sensor_names=tuple(mapping[k] for k in present),
        accelerations=None if rec.accelerations is None else np.ascontiguousarray(rec.accelerations[:, cols]),
        orientations=None if rec.orientations is None else np.ascontiguousarray(rec.orientations[:, cols]),
        meta=meta,
    )
    out.validate()
    return out
