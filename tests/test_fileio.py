"""Input files: a missing file is worded one way by every reader ("<path>: no such
file", after what the file is for where the reader knows it), a folder and
undecodable text are the project's errors too."""

from __future__ import annotations

import pytest

from graphsvc.errors import FormatError, MissingFileError


def _readers():
    from graphsvc.batch.manifest import read_manifest
    from graphsvc.evaluate.protocols import load_actor_map
    from graphsvc.graph.file import load_graph
    from graphsvc.motion.asfamc import read_asf, read_asf_amc
    from graphsvc.motion.bvh import read_bvh
    from graphsvc.motion.joints import load_mapping_file
    from graphsvc.sensors.calibration import load_calibration
    from graphsvc.sensors.devices import load_device_map, read_mvnx
    from graphsvc.sensors.files import read_recording
    from graphsvc.sensors.optical import read_c3d, read_marker_csv
    from graphsvc.sensors.recording import load_recording
    from graphsvc.service.client import read_token_file
    from graphsvc.service.interceptors import read_tokens
    from graphsvc.strategies.options import load_constraints

    return {
        "bvh": (read_bvh, "x.bvh", ""),
        "asf": (read_asf, "x.asf", ""),
        "amc": (read_asf_amc, "x.amc", ""),
        "rec": (load_recording, "x.rec", ""),
        "device csv": (read_recording, "x.csv", ""),
        "marker csv": (read_marker_csv, "x.csv", ""),
        "c3d": (read_c3d, "x.c3d", ""),
        "mvnx": (read_mvnx, "x.mvnx", ""),
        "graph": (load_graph, "x.graph", ""),
        "manifest": (read_manifest, "m.csv", "manifest"),
        "constraints": (load_constraints, "c.json", ""),
        "calibration": (load_calibration, "CAL.json", ""),
        "joint mapping": (load_mapping_file, "map.json", "joint mapping"),
        "actor map": (load_actor_map, "actors.json", "actor map"),
        "device map": (load_device_map, "dev.json", "device map"),
        "server tokens": (read_tokens, "tokens.txt", "token file"),
        "client token": (read_token_file, "token.txt", "token file"),
    }


@pytest.mark.parametrize("kind", list(_readers()))
def test_a_missing_input_file_is_worded_one_way(tmp_path, kind):
    reader, name, what = _readers()[kind]
    path = tmp_path / name
    with pytest.raises(MissingFileError) as info:
        reader(path)
    assert str(info.value) == (f"{what}: " if what else "") + f"{path}: no such file"


def test_a_folder_and_undecodable_text_are_format_errors(tmp_path):
    from graphsvc.fileio import read_input_text, read_json_file, require_file

    with pytest.raises(FormatError, match="is a folder, not a file"):
        read_input_text(tmp_path)
    with pytest.raises(FormatError, match="is a folder, not a file"):
        require_file(tmp_path)
    bad = tmp_path / "bad.json"
    bad.write_bytes(b'{"a": "\xff"}')
    with pytest.raises(FormatError, match="not UTF-8 text"):
        read_json_file(bad)
    bad.write_text('{"a": 1,\n}')
    with pytest.raises(FormatError, match=r"bad.json:2: not valid JSON"):
        read_json_file(bad)


def test_several_files_are_renamed_into_place_in_order_after_all_are_written(tmp_path, monkeypatch):
    import os

    from graphsvc.fileio import write_texts_atomic

    renamed = []
    real = os.replace

    def record(src, dst):
        # every file is complete (written, beside its target) before the first rename
        assert sorted(p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")) != [] or renamed
        renamed.append(os.path.basename(dst))
        real(src, dst)

    monkeypatch.setattr(os, "replace", record)
    write_texts_atomic([(tmp_path / "a.json", "{}"), (tmp_path / "b.bvh", "HIERARCHY")])
    assert renamed == ["a.json", "b.bvh"]
    assert (tmp_path / "a.json").read_text() == "{}" and (tmp_path / "b.bvh").read_text() == "HIERARCHY"


def test_a_failed_write_of_several_files_leaves_none_and_no_temporaries(tmp_path):
    from graphsvc.errors import InputError
    from graphsvc.fileio import write_texts_atomic

    with pytest.raises(InputError):  # the second file's folder is missing
        write_texts_atomic([(tmp_path / "a.json", "{}"), (tmp_path / "missing" / "b.bvh", "x")])
    assert list(tmp_path.iterdir()) == []
