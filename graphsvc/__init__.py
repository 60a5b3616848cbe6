"""graphsvc: full-body human motion from sparse measurements by searching motion capture.

The public API (`__all__`, the names docs/python-api.md uses) is resolved lazily: the
first use of `graphsvc.reconstruct`, say, imports the module that defines it (PEP 562,
a module `__getattr__`), so `import graphsvc` and the command line's start-up import
none of them. `from graphsvc import reconstruct` works as usual; a type checker reads
the same names from the imports under `TYPE_CHECKING` below.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from graphsvc import numba_env as _numba_env

_numba_env.configure()  # before numpy loads OpenBLAS and numba starts its threads (graphsvc/numba_env.py)

from graphsvc import kernel_cache as _kernel_cache  # noqa: E402

_kernel_cache.install()  # before any kernel is compiled (graphsvc/kernel_cache.py)

# Each public name → the module that defines it, in the order of the guide.
_API = {
    # motion: clips as flat arrays, their files, the procedural knowledge base
    "Motion": "graphsvc.motion.skeleton",
    "Skeleton": "graphsvc.motion.skeleton",
    "load_motion": "graphsvc.motion.library",
    "load_motions": "graphsvc.motion.library",
    "find_motion_files": "graphsvc.motion.library",
    "read_bvh": "graphsvc.motion.bvh",
    "write_bvh": "graphsvc.motion.bvh",
    "generate_knowledge_base": "graphsvc.motion.procedural",
    "generate_performance": "graphsvc.motion.procedural",
    # the motion graph
    "BuildOptions": "graphsvc.graph.build",
    "build_graph": "graphsvc.graph.build",
    "MotionGraph": "graphsvc.graph.model",
    "save_graph": "graphsvc.graph.file",
    "load_graph": "graphsvc.graph.file",
    "node_poses": "graphsvc.graph.poses",
    # sensors and recordings
    "Layout": "graphsvc.sensors.layout",
    "load_layout": "graphsvc.sensors.layout",
    "NoiseModel": "graphsvc.sensors.noise",
    "parse_noise": "graphsvc.sensors.noise",
    "MarkerPattern": "graphsvc.sensors.simulate",
    "simulate_recording": "graphsvc.sensors.simulate",
    "simulate_marker_recording": "graphsvc.sensors.simulate",
    "Recording": "graphsvc.sensors.recording",
    "save_recording": "graphsvc.sensors.recording",
    "load_recording": "graphsvc.sensors.recording",
    "read_recording": "graphsvc.sensors.files",
    # reconstruction, batch and live
    "Options": "graphsvc.strategies.options",
    "SharedOptions": "graphsvc.strategies.options",
    "Weights": "graphsvc.strategies.options",
    "ViterbiOptions": "graphsvc.strategies.viterbi.options",
    "OlngOptions": "graphsvc.strategies.olng.options",
    "SsgOptions": "graphsvc.strategies.ssg.options",
    "PiecewiseOptions": "graphsvc.strategies.piecewise.options",
    "reconstruct": "graphsvc.pipeline",
    "Reconstruction": "graphsvc.strategies.results",
    "Provenance": "graphsvc.strategies.results",
    "Frame": "graphsvc.strategies.results",
    "open_session": "graphsvc.strategies",
    "LiveSession": "graphsvc.strategies.live",
    # evaluation
    "truth_errors": "graphsvc.evaluate.metrics",
    "EvalSetup": "graphsvc.evaluate.loo",
    "run_leave_one_out": "graphsvc.evaluate.loo",
    "summarize_run": "graphsvc.evaluate.loo",
    # errors
    "GraphsvcError": "graphsvc.errors",
    "InputError": "graphsvc.errors",
}

__all__ = list(_API)


def __getattr__(name: str) -> Any:
    """A public name, imported from its module on first use and kept here."""
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'graphsvc' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value  # (the next lookup does not come here)
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:
    from graphsvc.errors import GraphsvcError, InputError
    from graphsvc.evaluate.loo import EvalSetup, run_leave_one_out, summarize_run
    from graphsvc.evaluate.metrics import truth_errors
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.graph.file import load_graph, save_graph
    from graphsvc.graph.model import MotionGraph
    from graphsvc.motion.bvh import read_bvh, write_bvh
    from graphsvc.motion.library import find_motion_files, load_motion, load_motions
    from graphsvc.motion.procedural import generate_knowledge_base, generate_performance
    from graphsvc.motion.skeleton import Motion, Skeleton
    from graphsvc.pipeline import reconstruct
    from graphsvc.sensors.files import read_recording
    from graphsvc.sensors.layout import Layout, load_layout
    from graphsvc.sensors.noise import NoiseModel, parse_noise
    from graphsvc.sensors.recording import Recording, load_recording, save_recording
    from graphsvc.sensors.simulate import MarkerPattern, simulate_marker_recording, simulate_recording
    from graphsvc.strategies import open_session
    from graphsvc.strategies.live import LiveSession
    from graphsvc.strategies.olng.options import OlngOptions
    from graphsvc.strategies.options import Options, SharedOptions, Weights
    from graphsvc.strategies.piecewise.options import PiecewiseOptions
    from graphsvc.strategies.results import Frame, Provenance, Reconstruction
    from graphsvc.strategies.ssg.options import SsgOptions
    from graphsvc.strategies.viterbi.options import ViterbiOptions
