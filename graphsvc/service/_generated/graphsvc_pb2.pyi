from google.protobuf import struct_pb2 as _struct_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Strategy(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    STRATEGY_UNSPECIFIED: _ClassVar[Strategy]
    STRATEGY_VITERBI: _ClassVar[Strategy]
    STRATEGY_OLNG: _ClassVar[Strategy]
    STRATEGY_SSG: _ClassVar[Strategy]
    STRATEGY_NEAREST: _ClassVar[Strategy]

class ContactState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    CONTACT_STATE_UNSPECIFIED: _ClassVar[ContactState]
    CONTACT_STATE_LEFT: _ClassVar[ContactState]
    CONTACT_STATE_RIGHT: _ClassVar[ContactState]
    CONTACT_STATE_BOTH: _ClassVar[ContactState]
    CONTACT_STATE_NONE: _ClassVar[ContactState]
STRATEGY_UNSPECIFIED: Strategy
STRATEGY_VITERBI: Strategy
STRATEGY_OLNG: Strategy
STRATEGY_SSG: Strategy
STRATEGY_NEAREST: Strategy
CONTACT_STATE_UNSPECIFIED: ContactState
CONTACT_STATE_LEFT: ContactState
CONTACT_STATE_RIGHT: ContactState
CONTACT_STATE_BOTH: ContactState
CONTACT_STATE_NONE: ContactState

class ListGraphsRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListGraphsResponse(_message.Message):
    __slots__ = ("graphs",)
    GRAPHS_FIELD_NUMBER: _ClassVar[int]
    graphs: _containers.RepeatedCompositeFieldContainer[GraphInfo]
    def __init__(self, graphs: _Optional[_Iterable[_Union[GraphInfo, _Mapping]]] = ...) -> None: ...

class GetGraphRequest(_message.Message):
    __slots__ = ("name",)
    NAME_FIELD_NUMBER: _ClassVar[int]
    name: str
    def __init__(self, name: _Optional[str] = ...) -> None: ...

class GetGraphResponse(_message.Message):
    __slots__ = ("graph",)
    GRAPH_FIELD_NUMBER: _ClassVar[int]
    graph: GraphInfo
    def __init__(self, graph: _Optional[_Union[GraphInfo, _Mapping]] = ...) -> None: ...

class GraphInfo(_message.Message):
    __slots__ = ("name", "node_count", "edge_count", "node_counts_by_kind", "edge_counts_by_kind", "dead_end_count", "clip_count", "kb_frame_count", "kb_minutes", "labels", "layout", "sensor_names", "rate_hz", "joint_count", "interpolated_segment_count", "file_bytes", "params", "skeleton", "rest_pose_accelerations_m_s2", "bridge_count", "sensor_orientations", "kb_original_frame_count")
    class NodeCountsByKindEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    class EdgeCountsByKindEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    NAME_FIELD_NUMBER: _ClassVar[int]
    NODE_COUNT_FIELD_NUMBER: _ClassVar[int]
    EDGE_COUNT_FIELD_NUMBER: _ClassVar[int]
    NODE_COUNTS_BY_KIND_FIELD_NUMBER: _ClassVar[int]
    EDGE_COUNTS_BY_KIND_FIELD_NUMBER: _ClassVar[int]
    DEAD_END_COUNT_FIELD_NUMBER: _ClassVar[int]
    CLIP_COUNT_FIELD_NUMBER: _ClassVar[int]
    KB_FRAME_COUNT_FIELD_NUMBER: _ClassVar[int]
    KB_MINUTES_FIELD_NUMBER: _ClassVar[int]
    LABELS_FIELD_NUMBER: _ClassVar[int]
    LAYOUT_FIELD_NUMBER: _ClassVar[int]
    SENSOR_NAMES_FIELD_NUMBER: _ClassVar[int]
    RATE_HZ_FIELD_NUMBER: _ClassVar[int]
    JOINT_COUNT_FIELD_NUMBER: _ClassVar[int]
    INTERPOLATED_SEGMENT_COUNT_FIELD_NUMBER: _ClassVar[int]
    FILE_BYTES_FIELD_NUMBER: _ClassVar[int]
    PARAMS_FIELD_NUMBER: _ClassVar[int]
    SKELETON_FIELD_NUMBER: _ClassVar[int]
    REST_POSE_ACCELERATIONS_M_S2_FIELD_NUMBER: _ClassVar[int]
    BRIDGE_COUNT_FIELD_NUMBER: _ClassVar[int]
    SENSOR_ORIENTATIONS_FIELD_NUMBER: _ClassVar[int]
    KB_ORIGINAL_FRAME_COUNT_FIELD_NUMBER: _ClassVar[int]
    name: str
    node_count: int
    edge_count: int
    node_counts_by_kind: _containers.ScalarMap[str, int]
    edge_counts_by_kind: _containers.ScalarMap[str, int]
    dead_end_count: int
    clip_count: int
    kb_frame_count: int
    kb_minutes: float
    labels: _containers.RepeatedScalarFieldContainer[str]
    layout: str
    sensor_names: _containers.RepeatedScalarFieldContainer[str]
    rate_hz: float
    joint_count: int
    interpolated_segment_count: int
    file_bytes: int
    params: _struct_pb2.Struct
    skeleton: Skeleton
    rest_pose_accelerations_m_s2: _containers.RepeatedScalarFieldContainer[float]
    bridge_count: int
    sensor_orientations: bool
    kb_original_frame_count: int
    def __init__(self, name: _Optional[str] = ..., node_count: _Optional[int] = ..., edge_count: _Optional[int] = ..., node_counts_by_kind: _Optional[_Mapping[str, int]] = ..., edge_counts_by_kind: _Optional[_Mapping[str, int]] = ..., dead_end_count: _Optional[int] = ..., clip_count: _Optional[int] = ..., kb_frame_count: _Optional[int] = ..., kb_minutes: _Optional[float] = ..., labels: _Optional[_Iterable[str]] = ..., layout: _Optional[str] = ..., sensor_names: _Optional[_Iterable[str]] = ..., rate_hz: _Optional[float] = ..., joint_count: _Optional[int] = ..., interpolated_segment_count: _Optional[int] = ..., file_bytes: _Optional[int] = ..., params: _Optional[_Union[_struct_pb2.Struct, _Mapping]] = ..., skeleton: _Optional[_Union[Skeleton, _Mapping]] = ..., rest_pose_accelerations_m_s2: _Optional[_Iterable[float]] = ..., bridge_count: _Optional[int] = ..., sensor_orientations: _Optional[bool] = ..., kb_original_frame_count: _Optional[int] = ...) -> None: ...

class Skeleton(_message.Message):
    __slots__ = ("joint_names", "parent_indices", "offsets_m", "channels", "end_sites")
    JOINT_NAMES_FIELD_NUMBER: _ClassVar[int]
    PARENT_INDICES_FIELD_NUMBER: _ClassVar[int]
    OFFSETS_M_FIELD_NUMBER: _ClassVar[int]
    CHANNELS_FIELD_NUMBER: _ClassVar[int]
    END_SITES_FIELD_NUMBER: _ClassVar[int]
    joint_names: _containers.RepeatedScalarFieldContainer[str]
    parent_indices: _containers.RepeatedScalarFieldContainer[int]
    offsets_m: _containers.RepeatedScalarFieldContainer[float]
    channels: _containers.RepeatedCompositeFieldContainer[JointChannels]
    end_sites: _containers.RepeatedScalarFieldContainer[bool]
    def __init__(self, joint_names: _Optional[_Iterable[str]] = ..., parent_indices: _Optional[_Iterable[int]] = ..., offsets_m: _Optional[_Iterable[float]] = ..., channels: _Optional[_Iterable[_Union[JointChannels, _Mapping]]] = ..., end_sites: _Optional[_Iterable[bool]] = ...) -> None: ...

class JointChannels(_message.Message):
    __slots__ = ("names",)
    NAMES_FIELD_NUMBER: _ClassVar[int]
    names: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, names: _Optional[_Iterable[str]] = ...) -> None: ...

class SynthesisOptions(_message.Message):
    __slots__ = ("strategy", "weights", "latency_s", "heading_from_track", "rest_heading_deg", "constraint_sets", "speed_threshold_m_s", "beam", "viterbi", "olng", "ssg", "strategy_name", "strategy_settings", "shared_settings")
    STRATEGY_FIELD_NUMBER: _ClassVar[int]
    WEIGHTS_FIELD_NUMBER: _ClassVar[int]
    LATENCY_S_FIELD_NUMBER: _ClassVar[int]
    HEADING_FROM_TRACK_FIELD_NUMBER: _ClassVar[int]
    REST_HEADING_DEG_FIELD_NUMBER: _ClassVar[int]
    CONSTRAINT_SETS_FIELD_NUMBER: _ClassVar[int]
    SPEED_THRESHOLD_M_S_FIELD_NUMBER: _ClassVar[int]
    BEAM_FIELD_NUMBER: _ClassVar[int]
    VITERBI_FIELD_NUMBER: _ClassVar[int]
    OLNG_FIELD_NUMBER: _ClassVar[int]
    SSG_FIELD_NUMBER: _ClassVar[int]
    STRATEGY_NAME_FIELD_NUMBER: _ClassVar[int]
    STRATEGY_SETTINGS_FIELD_NUMBER: _ClassVar[int]
    SHARED_SETTINGS_FIELD_NUMBER: _ClassVar[int]
    strategy: Strategy
    weights: CostWeights
    latency_s: float
    heading_from_track: bool
    rest_heading_deg: float
    constraint_sets: _containers.RepeatedCompositeFieldContainer[ConstraintSet]
    speed_threshold_m_s: float
    beam: float
    viterbi: ViterbiOptions
    olng: OlngOptions
    ssg: SsgOptions
    strategy_name: str
    strategy_settings: _struct_pb2.Struct
    shared_settings: _struct_pb2.Struct
    def __init__(self, strategy: _Optional[_Union[Strategy, str]] = ..., weights: _Optional[_Union[CostWeights, _Mapping]] = ..., latency_s: _Optional[float] = ..., heading_from_track: _Optional[bool] = ..., rest_heading_deg: _Optional[float] = ..., constraint_sets: _Optional[_Iterable[_Union[ConstraintSet, _Mapping]]] = ..., speed_threshold_m_s: _Optional[float] = ..., beam: _Optional[float] = ..., viterbi: _Optional[_Union[ViterbiOptions, _Mapping]] = ..., olng: _Optional[_Union[OlngOptions, _Mapping]] = ..., ssg: _Optional[_Union[SsgOptions, _Mapping]] = ..., strategy_name: _Optional[str] = ..., strategy_settings: _Optional[_Union[_struct_pb2.Struct, _Mapping]] = ..., shared_settings: _Optional[_Union[_struct_pb2.Struct, _Mapping]] = ...) -> None: ...

class OlngOptions(_message.Message):
    __slots__ = ("k", "i", "m", "basic_steps", "w_prior", "w_contr", "w_pose", "w_motion", "w_smooth", "fix_feet", "track_pull_s")
    K_FIELD_NUMBER: _ClassVar[int]
    I_FIELD_NUMBER: _ClassVar[int]
    M_FIELD_NUMBER: _ClassVar[int]
    BASIC_STEPS_FIELD_NUMBER: _ClassVar[int]
    W_PRIOR_FIELD_NUMBER: _ClassVar[int]
    W_CONTR_FIELD_NUMBER: _ClassVar[int]
    W_POSE_FIELD_NUMBER: _ClassVar[int]
    W_MOTION_FIELD_NUMBER: _ClassVar[int]
    W_SMOOTH_FIELD_NUMBER: _ClassVar[int]
    FIX_FEET_FIELD_NUMBER: _ClassVar[int]
    TRACK_PULL_S_FIELD_NUMBER: _ClassVar[int]
    k: int
    i: int
    m: int
    basic_steps: bool
    w_prior: float
    w_contr: float
    w_pose: float
    w_motion: float
    w_smooth: float
    fix_feet: bool
    track_pull_s: float
    def __init__(self, k: _Optional[int] = ..., i: _Optional[int] = ..., m: _Optional[int] = ..., basic_steps: _Optional[bool] = ..., w_prior: _Optional[float] = ..., w_contr: _Optional[float] = ..., w_pose: _Optional[float] = ..., w_motion: _Optional[float] = ..., w_smooth: _Optional[float] = ..., fix_feet: _Optional[bool] = ..., track_pull_s: _Optional[float] = ...) -> None: ...

class SsgOptions(_message.Message):
    __slots__ = ("markers", "keep", "window_s", "overlap_s", "k", "weight", "offsets")
    MARKERS_FIELD_NUMBER: _ClassVar[int]
    KEEP_FIELD_NUMBER: _ClassVar[int]
    WINDOW_S_FIELD_NUMBER: _ClassVar[int]
    OVERLAP_S_FIELD_NUMBER: _ClassVar[int]
    K_FIELD_NUMBER: _ClassVar[int]
    WEIGHT_FIELD_NUMBER: _ClassVar[int]
    OFFSETS_FIELD_NUMBER: _ClassVar[int]
    markers: str
    keep: _containers.RepeatedScalarFieldContainer[str]
    window_s: float
    overlap_s: float
    k: int
    weight: float
    offsets: str
    def __init__(self, markers: _Optional[str] = ..., keep: _Optional[_Iterable[str]] = ..., window_s: _Optional[float] = ..., overlap_s: _Optional[float] = ..., k: _Optional[int] = ..., weight: _Optional[float] = ..., offsets: _Optional[str] = ...) -> None: ...

class ViterbiOptions(_message.Message):
    __slots__ = ("beam", "heading_from_track", "rest_heading_deg", "speed_threshold_m_s", "track_pull_s")
    BEAM_FIELD_NUMBER: _ClassVar[int]
    HEADING_FROM_TRACK_FIELD_NUMBER: _ClassVar[int]
    REST_HEADING_DEG_FIELD_NUMBER: _ClassVar[int]
    SPEED_THRESHOLD_M_S_FIELD_NUMBER: _ClassVar[int]
    TRACK_PULL_S_FIELD_NUMBER: _ClassVar[int]
    beam: float
    heading_from_track: bool
    rest_heading_deg: float
    speed_threshold_m_s: float
    track_pull_s: float
    def __init__(self, beam: _Optional[float] = ..., heading_from_track: _Optional[bool] = ..., rest_heading_deg: _Optional[float] = ..., speed_threshold_m_s: _Optional[float] = ..., track_pull_s: _Optional[float] = ...) -> None: ...

class FrameSource(_message.Message):
    __slots__ = ("clip", "frame", "weight")
    CLIP_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    WEIGHT_FIELD_NUMBER: _ClassVar[int]
    clip: int
    frame: float
    weight: float
    def __init__(self, clip: _Optional[int] = ..., frame: _Optional[float] = ..., weight: _Optional[float] = ...) -> None: ...

class Provenance(_message.Message):
    __slots__ = ("sources_per_frame", "clips", "frames", "weights", "labels")
    SOURCES_PER_FRAME_FIELD_NUMBER: _ClassVar[int]
    CLIPS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    WEIGHTS_FIELD_NUMBER: _ClassVar[int]
    LABELS_FIELD_NUMBER: _ClassVar[int]
    sources_per_frame: int
    clips: _containers.RepeatedScalarFieldContainer[int]
    frames: _containers.RepeatedScalarFieldContainer[float]
    weights: _containers.RepeatedScalarFieldContainer[float]
    labels: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, sources_per_frame: _Optional[int] = ..., clips: _Optional[_Iterable[int]] = ..., frames: _Optional[_Iterable[float]] = ..., weights: _Optional[_Iterable[float]] = ..., labels: _Optional[_Iterable[str]] = ...) -> None: ...

class CostWeights(_message.Message):
    __slots__ = ("acceleration", "position", "heading", "orientation")
    ACCELERATION_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    HEADING_FIELD_NUMBER: _ClassVar[int]
    ORIENTATION_FIELD_NUMBER: _ClassVar[int]
    acceleration: float
    position: float
    heading: float
    orientation: float
    def __init__(self, acceleration: _Optional[float] = ..., position: _Optional[float] = ..., heading: _Optional[float] = ..., orientation: _Optional[float] = ...) -> None: ...

class ConstraintSet(_message.Message):
    __slots__ = ("constraints",)
    CONSTRAINTS_FIELD_NUMBER: _ClassVar[int]
    constraints: _containers.RepeatedCompositeFieldContainer[Constraint]
    def __init__(self, constraints: _Optional[_Iterable[_Union[Constraint, _Mapping]]] = ...) -> None: ...

class Constraint(_message.Message):
    __slots__ = ("start_s", "end_s", "contact", "label")
    START_S_FIELD_NUMBER: _ClassVar[int]
    END_S_FIELD_NUMBER: _ClassVar[int]
    CONTACT_FIELD_NUMBER: _ClassVar[int]
    LABEL_FIELD_NUMBER: _ClassVar[int]
    start_s: float
    end_s: float
    contact: ContactState
    label: str
    def __init__(self, start_s: _Optional[float] = ..., end_s: _Optional[float] = ..., contact: _Optional[_Union[ContactState, str]] = ..., label: _Optional[str] = ...) -> None: ...

class Recording(_message.Message):
    __slots__ = ("rate_hz", "sensor_names", "timestamps_s", "accelerations_m_s2", "ground_positions_m", "headings_rad", "orientations_wxyz", "marker_names", "marker_positions_m")
    RATE_HZ_FIELD_NUMBER: _ClassVar[int]
    SENSOR_NAMES_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMPS_S_FIELD_NUMBER: _ClassVar[int]
    ACCELERATIONS_M_S2_FIELD_NUMBER: _ClassVar[int]
    GROUND_POSITIONS_M_FIELD_NUMBER: _ClassVar[int]
    HEADINGS_RAD_FIELD_NUMBER: _ClassVar[int]
    ORIENTATIONS_WXYZ_FIELD_NUMBER: _ClassVar[int]
    MARKER_NAMES_FIELD_NUMBER: _ClassVar[int]
    MARKER_POSITIONS_M_FIELD_NUMBER: _ClassVar[int]
    rate_hz: float
    sensor_names: _containers.RepeatedScalarFieldContainer[str]
    timestamps_s: _containers.RepeatedScalarFieldContainer[float]
    accelerations_m_s2: _containers.RepeatedScalarFieldContainer[float]
    ground_positions_m: _containers.RepeatedScalarFieldContainer[float]
    headings_rad: _containers.RepeatedScalarFieldContainer[float]
    orientations_wxyz: _containers.RepeatedScalarFieldContainer[float]
    marker_names: _containers.RepeatedScalarFieldContainer[str]
    marker_positions_m: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, rate_hz: _Optional[float] = ..., sensor_names: _Optional[_Iterable[str]] = ..., timestamps_s: _Optional[_Iterable[float]] = ..., accelerations_m_s2: _Optional[_Iterable[float]] = ..., ground_positions_m: _Optional[_Iterable[float]] = ..., headings_rad: _Optional[_Iterable[float]] = ..., orientations_wxyz: _Optional[_Iterable[float]] = ..., marker_names: _Optional[_Iterable[str]] = ..., marker_positions_m: _Optional[_Iterable[float]] = ...) -> None: ...

class SynthesizeRequest(_message.Message):
    __slots__ = ("graph", "recording", "options", "calibrate_from_start", "performer")
    GRAPH_FIELD_NUMBER: _ClassVar[int]
    RECORDING_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    CALIBRATE_FROM_START_FIELD_NUMBER: _ClassVar[int]
    PERFORMER_FIELD_NUMBER: _ClassVar[int]
    graph: str
    recording: Recording
    options: SynthesisOptions
    calibrate_from_start: CalibrateFromStart
    performer: Performer
    def __init__(self, graph: _Optional[str] = ..., recording: _Optional[_Union[Recording, _Mapping]] = ..., options: _Optional[_Union[SynthesisOptions, _Mapping]] = ..., calibrate_from_start: _Optional[_Union[CalibrateFromStart, _Mapping]] = ..., performer: _Optional[_Union[Performer, _Mapping]] = ...) -> None: ...

class CalibrateFromStart(_message.Message):
    __slots__ = ("seconds", "pose")
    SECONDS_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    seconds: float
    pose: str
    def __init__(self, seconds: _Optional[float] = ..., pose: _Optional[str] = ...) -> None: ...

class Performer(_message.Message):
    __slots__ = ("height_m", "segments")
    HEIGHT_M_FIELD_NUMBER: _ClassVar[int]
    SEGMENTS_FIELD_NUMBER: _ClassVar[int]
    height_m: float
    segments: PerformerSegments
    def __init__(self, height_m: _Optional[float] = ..., segments: _Optional[_Union[PerformerSegments, _Mapping]] = ...) -> None: ...

class PerformerSegments(_message.Message):
    __slots__ = ("segments_m",)
    class SegmentsMEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    SEGMENTS_M_FIELD_NUMBER: _ClassVar[int]
    segments_m: _containers.ScalarMap[str, float]
    def __init__(self, segments_m: _Optional[_Mapping[str, float]] = ...) -> None: ...

class SynthesizeResponse(_message.Message):
    __slots__ = ("motion", "node_path", "bvh", "report", "provenance", "report_json")
    MOTION_FIELD_NUMBER: _ClassVar[int]
    NODE_PATH_FIELD_NUMBER: _ClassVar[int]
    BVH_FIELD_NUMBER: _ClassVar[int]
    REPORT_FIELD_NUMBER: _ClassVar[int]
    PROVENANCE_FIELD_NUMBER: _ClassVar[int]
    REPORT_JSON_FIELD_NUMBER: _ClassVar[int]
    motion: Motion
    node_path: _containers.RepeatedScalarFieldContainer[int]
    bvh: bytes
    report: _struct_pb2.Struct
    provenance: Provenance
    report_json: str
    def __init__(self, motion: _Optional[_Union[Motion, _Mapping]] = ..., node_path: _Optional[_Iterable[int]] = ..., bvh: _Optional[bytes] = ..., report: _Optional[_Union[_struct_pb2.Struct, _Mapping]] = ..., provenance: _Optional[_Union[Provenance, _Mapping]] = ..., report_json: _Optional[str] = ...) -> None: ...

class Motion(_message.Message):
    __slots__ = ("rate_hz", "frame_count", "joint_count", "rotations_wxyz", "translations_m")
    RATE_HZ_FIELD_NUMBER: _ClassVar[int]
    FRAME_COUNT_FIELD_NUMBER: _ClassVar[int]
    JOINT_COUNT_FIELD_NUMBER: _ClassVar[int]
    ROTATIONS_WXYZ_FIELD_NUMBER: _ClassVar[int]
    TRANSLATIONS_M_FIELD_NUMBER: _ClassVar[int]
    rate_hz: float
    frame_count: int
    joint_count: int
    rotations_wxyz: _containers.RepeatedScalarFieldContainer[float]
    translations_m: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, rate_hz: _Optional[float] = ..., frame_count: _Optional[int] = ..., joint_count: _Optional[int] = ..., rotations_wxyz: _Optional[_Iterable[float]] = ..., translations_m: _Optional[_Iterable[float]] = ...) -> None: ...

class StreamSynthesizeRequest(_message.Message):
    __slots__ = ("config", "sample")
    CONFIG_FIELD_NUMBER: _ClassVar[int]
    SAMPLE_FIELD_NUMBER: _ClassVar[int]
    config: StreamConfig
    sample: SensorSample
    def __init__(self, config: _Optional[_Union[StreamConfig, _Mapping]] = ..., sample: _Optional[_Union[SensorSample, _Mapping]] = ...) -> None: ...

class StreamConfig(_message.Message):
    __slots__ = ("graph", "options", "sensor_names", "marker_names", "orientations", "calibrate_from_start")
    GRAPH_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    SENSOR_NAMES_FIELD_NUMBER: _ClassVar[int]
    MARKER_NAMES_FIELD_NUMBER: _ClassVar[int]
    ORIENTATIONS_FIELD_NUMBER: _ClassVar[int]
    CALIBRATE_FROM_START_FIELD_NUMBER: _ClassVar[int]
    graph: str
    options: SynthesisOptions
    sensor_names: _containers.RepeatedScalarFieldContainer[str]
    marker_names: _containers.RepeatedScalarFieldContainer[str]
    orientations: bool
    calibrate_from_start: CalibrateFromStart
    def __init__(self, graph: _Optional[str] = ..., options: _Optional[_Union[SynthesisOptions, _Mapping]] = ..., sensor_names: _Optional[_Iterable[str]] = ..., marker_names: _Optional[_Iterable[str]] = ..., orientations: _Optional[bool] = ..., calibrate_from_start: _Optional[_Union[CalibrateFromStart, _Mapping]] = ...) -> None: ...

class SensorSample(_message.Message):
    __slots__ = ("time_s", "accelerations_m_s2", "ground_position", "heading_rad", "marker_positions_m", "orientations_wxyz")
    TIME_S_FIELD_NUMBER: _ClassVar[int]
    ACCELERATIONS_M_S2_FIELD_NUMBER: _ClassVar[int]
    GROUND_POSITION_FIELD_NUMBER: _ClassVar[int]
    HEADING_RAD_FIELD_NUMBER: _ClassVar[int]
    MARKER_POSITIONS_M_FIELD_NUMBER: _ClassVar[int]
    ORIENTATIONS_WXYZ_FIELD_NUMBER: _ClassVar[int]
    time_s: float
    accelerations_m_s2: _containers.RepeatedScalarFieldContainer[float]
    ground_position: GroundPosition
    heading_rad: float
    marker_positions_m: _containers.RepeatedScalarFieldContainer[float]
    orientations_wxyz: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, time_s: _Optional[float] = ..., accelerations_m_s2: _Optional[_Iterable[float]] = ..., ground_position: _Optional[_Union[GroundPosition, _Mapping]] = ..., heading_rad: _Optional[float] = ..., marker_positions_m: _Optional[_Iterable[float]] = ..., orientations_wxyz: _Optional[_Iterable[float]] = ...) -> None: ...

class GroundPosition(_message.Message):
    __slots__ = ("x_m", "z_m")
    X_M_FIELD_NUMBER: _ClassVar[int]
    Z_M_FIELD_NUMBER: _ClassVar[int]
    x_m: float
    z_m: float
    def __init__(self, x_m: _Optional[float] = ..., z_m: _Optional[float] = ...) -> None: ...

class StreamSynthesizeResponse(_message.Message):
    __slots__ = ("started", "frame", "finished")
    STARTED_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    FINISHED_FIELD_NUMBER: _ClassVar[int]
    started: StreamStarted
    frame: PoseFrame
    finished: StreamFinished
    def __init__(self, started: _Optional[_Union[StreamStarted, _Mapping]] = ..., frame: _Optional[_Union[PoseFrame, _Mapping]] = ..., finished: _Optional[_Union[StreamFinished, _Mapping]] = ...) -> None: ...

class StreamStarted(_message.Message):
    __slots__ = ("graph", "rate_hz", "lag_frames", "sensor_names", "skeleton")
    GRAPH_FIELD_NUMBER: _ClassVar[int]
    RATE_HZ_FIELD_NUMBER: _ClassVar[int]
    LAG_FRAMES_FIELD_NUMBER: _ClassVar[int]
    SENSOR_NAMES_FIELD_NUMBER: _ClassVar[int]
    SKELETON_FIELD_NUMBER: _ClassVar[int]
    graph: str
    rate_hz: float
    lag_frames: int
    sensor_names: _containers.RepeatedScalarFieldContainer[str]
    skeleton: Skeleton
    def __init__(self, graph: _Optional[str] = ..., rate_hz: _Optional[float] = ..., lag_frames: _Optional[int] = ..., sensor_names: _Optional[_Iterable[str]] = ..., skeleton: _Optional[_Union[Skeleton, _Mapping]] = ...) -> None: ...

class PoseFrame(_message.Message):
    __slots__ = ("index", "time_s", "node", "label", "rotations_wxyz", "translations_m", "input_sample_index", "sources")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    TIME_S_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    LABEL_FIELD_NUMBER: _ClassVar[int]
    ROTATIONS_WXYZ_FIELD_NUMBER: _ClassVar[int]
    TRANSLATIONS_M_FIELD_NUMBER: _ClassVar[int]
    INPUT_SAMPLE_INDEX_FIELD_NUMBER: _ClassVar[int]
    SOURCES_FIELD_NUMBER: _ClassVar[int]
    index: int
    time_s: float
    node: int
    label: str
    rotations_wxyz: _containers.RepeatedScalarFieldContainer[float]
    translations_m: _containers.RepeatedScalarFieldContainer[float]
    input_sample_index: int
    sources: _containers.RepeatedCompositeFieldContainer[FrameSource]
    def __init__(self, index: _Optional[int] = ..., time_s: _Optional[float] = ..., node: _Optional[int] = ..., label: _Optional[str] = ..., rotations_wxyz: _Optional[_Iterable[float]] = ..., translations_m: _Optional[_Iterable[float]] = ..., input_sample_index: _Optional[int] = ..., sources: _Optional[_Iterable[_Union[FrameSource, _Mapping]]] = ...) -> None: ...

class StreamFinished(_message.Message):
    __slots__ = ("samples_received", "frames_emitted")
    SAMPLES_RECEIVED_FIELD_NUMBER: _ClassVar[int]
    FRAMES_EMITTED_FIELD_NUMBER: _ClassVar[int]
    samples_received: int
    frames_emitted: int
    def __init__(self, samples_received: _Optional[int] = ..., frames_emitted: _Optional[int] = ...) -> None: ...

class SubmitBatchRequest(_message.Message):
    __slots__ = ("manifest", "format", "retries")
    MANIFEST_FIELD_NUMBER: _ClassVar[int]
    FORMAT_FIELD_NUMBER: _ClassVar[int]
    RETRIES_FIELD_NUMBER: _ClassVar[int]
    manifest: str
    format: str
    retries: int
    def __init__(self, manifest: _Optional[str] = ..., format: _Optional[str] = ..., retries: _Optional[int] = ...) -> None: ...

class GetBatchRequest(_message.Message):
    __slots__ = ("batch_id", "items")
    BATCH_ID_FIELD_NUMBER: _ClassVar[int]
    ITEMS_FIELD_NUMBER: _ClassVar[int]
    batch_id: str
    items: bool
    def __init__(self, batch_id: _Optional[str] = ..., items: _Optional[bool] = ...) -> None: ...

class ListBatchesRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListBatchesResponse(_message.Message):
    __slots__ = ("batches",)
    BATCHES_FIELD_NUMBER: _ClassVar[int]
    batches: _containers.RepeatedCompositeFieldContainer[BatchStatus]
    def __init__(self, batches: _Optional[_Iterable[_Union[BatchStatus, _Mapping]]] = ...) -> None: ...

class CancelBatchRequest(_message.Message):
    __slots__ = ("batch_id",)
    BATCH_ID_FIELD_NUMBER: _ClassVar[int]
    batch_id: str
    def __init__(self, batch_id: _Optional[str] = ...) -> None: ...

class BatchStatus(_message.Message):
    __slots__ = ("batch_id", "state", "items", "queued", "running", "done", "failed", "error", "submitted_unix_s", "folder", "item_status")
    BATCH_ID_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    ITEMS_FIELD_NUMBER: _ClassVar[int]
    QUEUED_FIELD_NUMBER: _ClassVar[int]
    RUNNING_FIELD_NUMBER: _ClassVar[int]
    DONE_FIELD_NUMBER: _ClassVar[int]
    FAILED_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    SUBMITTED_UNIX_S_FIELD_NUMBER: _ClassVar[int]
    FOLDER_FIELD_NUMBER: _ClassVar[int]
    ITEM_STATUS_FIELD_NUMBER: _ClassVar[int]
    batch_id: str
    state: str
    items: int
    queued: int
    running: int
    done: int
    failed: int
    error: str
    submitted_unix_s: float
    folder: str
    item_status: _containers.RepeatedCompositeFieldContainer[BatchItem]
    def __init__(self, batch_id: _Optional[str] = ..., state: _Optional[str] = ..., items: _Optional[int] = ..., queued: _Optional[int] = ..., running: _Optional[int] = ..., done: _Optional[int] = ..., failed: _Optional[int] = ..., error: _Optional[str] = ..., submitted_unix_s: _Optional[float] = ..., folder: _Optional[str] = ..., item_status: _Optional[_Iterable[_Union[BatchItem, _Mapping]]] = ...) -> None: ...

class BatchItem(_message.Message):
    __slots__ = ("output", "line", "state", "attempts", "reason", "seconds", "output_path", "checksum")
    OUTPUT_FIELD_NUMBER: _ClassVar[int]
    LINE_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    ATTEMPTS_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    SECONDS_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_PATH_FIELD_NUMBER: _ClassVar[int]
    CHECKSUM_FIELD_NUMBER: _ClassVar[int]
    output: str
    line: int
    state: str
    attempts: int
    reason: str
    seconds: float
    output_path: str
    checksum: str
    def __init__(self, output: _Optional[str] = ..., line: _Optional[int] = ..., state: _Optional[str] = ..., attempts: _Optional[int] = ..., reason: _Optional[str] = ..., seconds: _Optional[float] = ..., output_path: _Optional[str] = ..., checksum: _Optional[str] = ...) -> None: ...
