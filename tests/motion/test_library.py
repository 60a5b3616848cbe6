"""Dispatch, labels and file discovery."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from graphsvc.errors import FormatError, UnknownFormatError
from graphsvc.motion.library import content_label, find_motion_files, load_motion, load_motions
from tests.motion.test_asfamc import AMC, ASF
from tests.motion.test_bvh import SIMPLE


def put(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture
def tree(tmp_path) -> Path:
    """A Bandai-like dataset folder with cfg tables, a CMU-like folder, and junk."""
    ds = tmp_path / "dataset-2"
    put(ds / "cfg" / "content_label.txt", "dataset-2_walk\ndataset-2_run\ndataset-2_wave-both-hands")
    put(ds / "cfg" / "style_label.txt", "dataset-2_active\ndataset-2_normal")
    put(ds / "data" / "dataset-2_run_normal_001.bvh", SIMPLE)
    put(ds / "data" / "dataset-2_run_normal_001.json", json.dumps({"content": 1, "style": 1}))
    put(ds / "data" / "dataset-2_walk_normal_001.bvh", SIMPLE)  # no sidecar: from the name
    put(ds / "data" / "notes.txt", "not a motion")
    put(tmp_path / "cmu" / "07" / "07.asf", ASF)
    put(tmp_path / "cmu" / "07" / "07_01.amc", AMC)
    put(tmp_path / "cmu" / "07" / "07_01.tags", "jump\n# comment\n\nplayground\njump\n")
    return tmp_path


def test_load_motion_fills_name_source_labels(tree):
    path = tree / "dataset-2" / "data" / "dataset-2_run_normal_001.bvh"
    m = load_motion(path)
    assert m.name == "dataset-2_run_normal_001"
    assert m.source == str(path)
    assert m.labels == ("run",)
    assert load_motion(tree / "dataset-2" / "data" / "dataset-2_walk_normal_001.bvh").labels == ("walk",)
    amc = load_motion(tree / "cmu" / "07" / "07_01.amc", rate_hz=60.0)
    assert amc.labels == ("07_01", "jump", "playground")
    assert amc.rate_hz == 60.0 and amc.name == "07_01"


def test_options_pass_through(tree):
    m = load_motion(tree / "dataset-2" / "data" / "dataset-2_walk_normal_001.bvh", scale=1.0)
    assert m.skeleton.offsets[2, 1] == 50.0


def test_sidecar_without_cfg_and_bad_json(tree):
    path = put(tree / "flat" / "dataset-1_bow_happy_002.bvh", SIMPLE)
    put(tree / "flat" / "dataset-1_bow_happy_002.json", json.dumps({"content": 3}))
    assert content_label(path) == "bow"  # no cfg table: from the file name
    put(tree / "flat" / "dataset-1_bow_happy_002.json", "{broken")
    with pytest.raises(FormatError, match="not valid JSON"):
        load_motion(path)
    put(tree / "dataset-2" / "data" / "dataset-2_run_normal_001.json", json.dumps({"content": 9}))
    with pytest.raises(FormatError, match="content id 9"):
        load_motion(tree / "dataset-2" / "data" / "dataset-2_run_normal_001.bvh")


def test_unknown_and_asf_paths(tree):
    with pytest.raises(UnknownFormatError, match="pass the .amc"):
        load_motion(tree / "cmu" / "07" / "07.asf")
    with pytest.raises(UnknownFormatError, match="unknown motion format"):
        load_motion(tree / "dataset-2" / "data" / "notes.txt")
    with pytest.raises(FormatError, match="no such file"):
        load_motion(tree / "missing.bvh")


def test_find_motion_files(tree):
    everything = find_motion_files([str(tree)])
    assert [p.name for p in everything] == [
        "07_01.amc",
        "dataset-2_run_normal_001.bvh",
        "dataset-2_walk_normal_001.bvh",
    ]
    assert everything == sorted(everything, key=lambda p: p.as_posix())
    # Patterns, duplicates, single files, exclusion by name and by path.
    found = find_motion_files(
        [str(tree / "**" / "*.bvh"), str(tree / "dataset-2" / "data" / "dataset-2_run_normal_001.bvh")]
    )
    assert [p.name for p in found] == ["dataset-2_run_normal_001.bvh", "dataset-2_walk_normal_001.bvh"]
    assert [p.name for p in find_motion_files([str(tree)], exclude=["*walk*"])] == [
        "07_01.amc",
        "dataset-2_run_normal_001.bvh",
    ]
    assert [p.name for p in find_motion_files([str(tree)], exclude=["*/cmu/*"])] == [
        "dataset-2_run_normal_001.bvh",
        "dataset-2_walk_normal_001.bvh",
    ]
    with pytest.raises(FormatError, match="nope: no such file"):
        find_motion_files([str(tree / "nope")])
    with pytest.raises(FormatError, match="no such file: the pattern"):
        find_motion_files([str(tree / "*.xyz")])
    with pytest.raises(UnknownFormatError):
        find_motion_files([str(tree / "dataset-2" / "data" / "notes.txt")])


def test_load_motions(tree):
    motions = load_motions([str(tree)], exclude=["*run*"])
    assert [m.labels[0] for m in motions] == ["07_01", "walk"]


def test_real_data_labels_match_file_names(data_dir):
    root = data_dir / "bandai"
    if not root.is_dir():
        pytest.skip(f"../shared/data not found: {root} missing")
    # datasets 1 and 2 as published (174 + 280 clips); dataset 2's further takes
    # 005–019 (1,048 clips) where they are shared too
    files = find_motion_files([str(root / "dataset-1"), str(root / "dataset-2")])
    assert len(files) == 454
    if (root / "dataset-2-extra").is_dir():
        extra = find_motion_files([str(root / "dataset-2-extra")])
        assert len(extra) == 1048 and len(find_motion_files([str(root)])) == 454 + 1048
        files += extra[::7]
    for f in files[::15]:
        # The JSON id through cfg/content_label.txt names the same content as the file.
        assert content_label(f) == f.stem.split("_")[1], f
    cmu = data_dir / "cmu"
    if cmu.is_dir():
        m = load_motion(cmu / "02" / "02_01.amc")
        assert m.labels[0] == "02_01" and m.rate_hz == 120.0


@pytest.mark.parametrize(
    "name, label",
    [
        ("dataset-2_walk_normal_001.bvh", "walk"),
        ("walk_03.bvh", "walk"),
        ("forehand-12.bvh", "forehand"),
        ("01_01.amc", "01_01"),
        ("serve.bvh", "serve"),
    ],
)
def test_content_label_from_file_name(tmp_path, name, label):
    assert content_label(tmp_path / name) == label
