"""The sample clips that install with pybullet (the optional extra `samples`): the
DeepMimic humanoid's motion files in `pybullet_data/data/motions` (walk, run, turns,
jump, kick, punch, spin kick, cartwheel, backflip, dances, crawl, roll, get-ups), read
with `motion.deepmimic`, written as BVH with pybullet's licence (`graphsvc samples`)
and the knowledge base of `graphsvc demo --kb pybullet`.

pybullet's wheel holds `pybullet_data` as a package of its own, found here without
importing pybullet (its simulator starts with a banner and takes a second).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
from pathlib import Path

from graphsvc.errors import GraphsvcError
from graphsvc.fileio import write_text_atomic
from graphsvc.motion.bvh import write_bvh
from graphsvc.motion.deepmimic import humanoid_character, is_deepmimic, sample_name
from graphsvc.motion.library import load_motion
from graphsvc.motion.skeleton import Motion

INSTALL_HINT = "pip install 'graphsvc[samples]' (in a clone: pip install -e '.[samples]')"
BVH_UNITS_PER_M = 100.0  # centimetres, what most BVH viewers expect
LICENCE_FILE = "LICENSE.txt"


class SamplesMissingError(GraphsvcError):
    """pybullet, which holds the sample clips, is not installed."""


def motions_dir() -> Path:
    """pybullet's folder of DeepMimic motion files; SamplesMissingError saying how to
    install it when pybullet is not installed."""
    spec = importlib.util.find_spec("pybullet_data")
    folder = Path(spec.origin).parent / "data" / "motions" if spec is not None and spec.origin else None
    if folder is None or not folder.is_dir():
        raise SamplesMissingError(f"the sample clips come with pybullet, which is not installed: {INSTALL_HINT}")
    return folder


def sample_files() -> list[Path]:
    """The humanoid's clips among pybullet's motion files (its folder and `walker/`),
    sorted by path: the DeepMimic files whose frames fit the humanoid (pybullet's
    quadruped clip does not)."""
    width = humanoid_character().frame_width
    out = []
    for path in sorted(motions_dir().rglob("*.txt"), key=lambda p: p.as_posix()):
        if not is_deepmimic(path):
            continue
        frames = json.loads(path.read_text(encoding="utf-8")).get("Frames") or [[]]
        if len(frames[0]) == width:
            out.append(path)
    return out


def load_samples() -> list[Motion]:
    """The sample clips as motions, each named as `graphsvc samples` writes it
    (`sample_name`: "walk", "turn_left_0", …)."""
    motions = []
    for path in sample_files():
        m = load_motion(path)
        m.name = sample_name(path.stem)
        motions.append(m)
    names = [m.name for m in motions]
    if len(set(names)) != len(names):
        raise GraphsvcError(f"pybullet's sample clips have clashing names: {sorted(names)}")
    return motions


def licence_text() -> str:
    """What the written clips carry: where they come from, as the installed pybullet
    says it, and its licence and authors files, word for word."""
    dist = importlib.metadata.distribution("pybullet")
    meta = dist.metadata

    def read(name: str) -> str:
        text = dist.read_text(name) or dist.read_text(f"licenses/{name}")
        return text.strip() if text else f"({name} is not in this pybullet installation)"

    return "\n".join(
        [
            f"These BVH files are the DeepMimic humanoid's motion files that pybullet {meta['Version']} installs",
            "in pybullet_data/data/motions (its DeepMimic environment, pybullet_envs.deep_mimic, reads them",
            "as motion capture data), converted by graphsvc (`graphsvc samples`): resampled to a uniform",
            "rate, turned to face +Z, in centimetres.",
            "",
            f"pybullet: {meta['Summary']}",
            f"Home page: {meta['Home-page']}",
            f"Licence: {meta['License']}",
            "",
            "pybullet's LICENSE.txt:",
            "",
            read("LICENSE.txt"),
            "",
            "pybullet's AUTHORS.txt:",
            "",
            read("AUTHORS.txt"),
            "",
        ]
    )


def write_samples(out_dir, motions: list[Motion] | None = None) -> list[Path]:
    """Write the sample clips (default: all of `load_samples`) as `<name>.bvh` into
    `out_dir` (created if missing; its parent must exist), with LICENSE.txt; each file
    written atomically. Returns the paths written."""
    out_dir = Path(out_dir)
    if not out_dir.parent.is_dir():
        raise GraphsvcError(f"output folder {out_dir.parent} does not exist")
    if out_dir.exists() and not out_dir.is_dir():
        raise GraphsvcError(f"{out_dir} is a file, not a folder")
    motions = load_samples() if motions is None else motions
    text = licence_text()
    out_dir.mkdir(exist_ok=True)
    written = []
    for m in motions:
        path = out_dir / f"{m.name}.bvh"
        write_bvh(path, m, scale=BVH_UNITS_PER_M)
        written.append(path)
    write_text_atomic(out_dir / LICENCE_FILE, text)
    return written + [out_dir / LICENCE_FILE]
