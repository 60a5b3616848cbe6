"""Shared fixtures: a tiny canonical T-pose skeleton for hand-checked cases, and the
location of ../shared/data for tests that read real motion capture."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion, Skeleton

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GRAPHSVC_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))

_TPOSE = [  # name, parent, offset (m): faces +Z, left is +X
    ("pelvis", None, (0.0, 0.96, 0.0)),
    ("spine", "pelvis", (0.0, 0.10, 0.0)),
    ("chest", "spine", (0.0, 0.20, 0.0)),
    ("neck", "chest", (0.0, 0.25, 0.0)),
    ("head", "neck", (0.0, 0.10, 0.0)),
    ("l_shoulder", "chest", (0.18, 0.20, 0.0)),
    ("l_elbow", "l_shoulder", (0.28, 0.0, 0.0)),
    ("l_wrist", "l_elbow", (0.25, 0.0, 0.0)),
    ("r_shoulder", "chest", (-0.18, 0.20, 0.0)),
    ("r_elbow", "r_shoulder", (-0.28, 0.0, 0.0)),
    ("r_wrist", "r_elbow", (-0.25, 0.0, 0.0)),
    ("l_hip", "pelvis", (0.10, -0.05, 0.0)),
    ("l_knee", "l_hip", (0.0, -0.42, 0.0)),
    ("l_ankle", "l_knee", (0.0, -0.42, 0.0)),
    ("l_toe", "l_ankle", (0.0, -0.07, 0.13)),
    ("r_hip", "pelvis", (-0.10, -0.05, 0.0)),
    ("r_knee", "r_hip", (0.0, -0.42, 0.0)),
    ("r_ankle", "r_knee", (0.0, -0.42, 0.0)),
    ("r_toe", "r_ankle", (0.0, -0.07, 0.13)),
]


def tpose_skeleton() -> Skeleton:
    names = tuple(n for n, _, _ in _TPOSE)
    parents = [-1 if p is None else names.index(p) for _, p, _ in _TPOSE]
    channels = tuple(
        ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
        if p is None
        else ("Zrotation", "Xrotation", "Yrotation")
        for _, p, _ in _TPOSE
    )
    return Skeleton(names, np.array(parents), np.array([o for _, _, o in _TPOSE]), channels, np.zeros(len(names), bool))


def still_motion(frames: int, rate_hz: float = 30.0) -> Motion:
    """The T-pose held for `frames` frames."""
    sk = tpose_skeleton()
    rot = quat.identity((frames, sk.num_joints))
    trans = np.broadcast_to(sk.offsets, (frames, sk.num_joints, 3)).copy()
    return Motion(sk, rot, trans, rate_hz, name="still")


def write_gliding_clip(folder: Path) -> Path:
    """walk_demo_001.bvh in `folder`: the T-pose gliding 1 m along +Z over 40 frames."""
    from graphsvc.motion.bvh import write_bvh

    m = still_motion(40)
    m.translations[:, 0, 2] = np.linspace(0, 1.0, 40)
    path = folder / "walk_demo_001.bvh"
    write_bvh(path, m, scale=100.0)
    return path


@pytest.fixture(autouse=True)
def _empty_working_directory(tmp_path_factory, monkeypatch):
    """Every test starts in an empty folder of its own: what the folder pytest was started
    from holds (a demo's output, say) never changes a result, and a test that writes
    into the working directory writes nowhere that matters. Child processes find this
    checkout's `graphsvc` and `tests` through PYTHONPATH, wherever they start."""
    monkeypatch.chdir(tmp_path_factory.mktemp("cwd"))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p))


@pytest.fixture
def skeleton() -> Skeleton:
    return tpose_skeleton()


@pytest.fixture
def data_dir() -> Path:
    if not DATA.is_dir():
        pytest.skip(f"../shared/data not found at {DATA} (set GRAPHSVC_DATA to run real-data tests)")
    return DATA


def write_procedural_kb(folder: Path, seed: int, minutes: float) -> Path:
    """A procedural knowledge base written as BVH files (centimetres) into `folder`."""
    from graphsvc.motion.bvh import write_bvh
    from graphsvc.motion.procedural import generate_knowledge_base

    for clip in generate_knowledge_base(seed=seed, minutes=minutes):
        write_bvh(folder / f"{clip.name}.bvh", clip, scale=100.0)
    return folder


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory):
    """`graphsvc demo` run once (seed 0, 0.6 minutes of knowledge base): (its summary,
    its output folder)."""
    from graphsvc.demo import run_demo

    out = tmp_path_factory.mktemp("demo") / "a"
    return run_demo(out, seed=0, minutes=0.6), out
