"""Protocol buffers ↔ graphsvc's objects, every conversion under one name: this module
only re-exports them from the modules that hold them, by what they convert, for
`from graphsvc.service import convert` and `convert.X`. Modules of the package import
from those directly.

convert_graph.py      Skeleton, GraphInfo (and its dict), the rest pose's readings
convert_recording.py  Recording, a stream's samples and marker names, sensor order
convert_motion.py     Motion, PoseFrame (and frames → Motion), Provenance
convert_report.py     a SynthesizeResponse's report, BatchStatus, Struct values
options_proto.py      SynthesisOptions and constraints, a Performer

Every `*_from_proto` checks what it reads and raises FieldError naming the field
(its path in the request, e.g. "recording.timestamps_s[12]"), which the server turns
into INVALID_ARGUMENT.
"""

from __future__ import annotations

from graphsvc.errors import FieldError
from graphsvc.service.convert_graph import (
    graph_info,
    graph_info_dict,
    rest_pose_readings,
    skeleton_from_proto,
    skeleton_to_proto,
)
from graphsvc.service.convert_motion import (
    frame_to_proto,
    frames_to_motion,
    motion_from_proto,
    motion_to_proto,
    provenance_to_proto,
)
from graphsvc.service.convert_recording import (
    marker_names_from_proto,
    recording_from_proto,
    recording_to_proto,
    sample_from_proto,
    sample_markers_from_proto,
    sample_orientations_from_proto,
    sample_to_proto,
    sensor_order,
)
from graphsvc.service.convert_report import (
    batch_status_to_proto,
    json_safe,
    report_from_proto,
    report_to_proto,
    struct_to_dict,
)
from graphsvc.service.options_proto import (
    constraints_from_proto,
    constraints_to_proto,
    for_recording,
    options_from_proto,
    options_to_proto,
    performer_from_proto,
    performer_to_proto,
)

__all__ = [
    "FieldError",
    # convert_graph
    "graph_info",
    "graph_info_dict",
    "rest_pose_readings",
    "skeleton_from_proto",
    "skeleton_to_proto",
    # convert_recording
    "marker_names_from_proto",
    "recording_from_proto",
    "recording_to_proto",
    "sample_from_proto",
    "sample_markers_from_proto",
    "sample_orientations_from_proto",
    "sample_to_proto",
    "sensor_order",
    # convert_motion
    "frame_to_proto",
    "frames_to_motion",
    "motion_from_proto",
    "motion_to_proto",
    "provenance_to_proto",
    # convert_report
    "batch_status_to_proto",
    "json_safe",
    "report_from_proto",
    "report_to_proto",
    "struct_to_dict",
    # options_proto
    "constraints_from_proto",
    "constraints_to_proto",
    "for_recording",
    "options_from_proto",
    "options_to_proto",
    "performer_from_proto",
    "performer_to_proto",
]
