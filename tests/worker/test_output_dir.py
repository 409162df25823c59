"""The worker's output folder: refused, resumed or replaced; stale temporaries removed;
run ids from the wire made safe as folder names."""

from __future__ import annotations

import json

import pytest

from svss_proc.run_folder import JOURNAL, MANIFEST, prepare_output_dir, run_folder_name


def test_folder_of_another_kind_is_refused_unless_forced(tmp_path):
    (tmp_path / "tile_0003.h5").write_bytes(b"old")
    with pytest.raises(FileExistsError, match=r"tile_0003.h5.*--force"):
        prepare_output_dir(tmp_path, resume=True)
    prepare_output_dir(tmp_path, force=True)
    assert not list(tmp_path.iterdir())


def test_worker_folder_is_resumed_and_its_debris_removed(tmp_path):
    run = tmp_path / "line1"
    run.mkdir()
    (run / JOURNAL).write_text(json.dumps({"schema": "svss.worker_state", "version": 1}))
    (run / "tile_0001.h5").write_bytes(b"done")
    (run / ".tile_0002.partial-0123abcd.h5").write_bytes(b"half")
    (run / "manifest.json.partial").write_text("{")
    (tmp_path / MANIFEST).write_text(json.dumps({"runs": {}, "files": []}))
    with pytest.raises(FileExistsError):
        prepare_output_dir(tmp_path)                   # not resumable: refused
    prepare_output_dir(tmp_path, resume=True)
    assert sorted(p.name for p in run.iterdir()) == sorted([JOURNAL, "tile_0001.h5"])
    prepare_output_dir(tmp_path, force=True, resume=True)
    assert not list(tmp_path.iterdir())


def test_idle_worker_folder_is_resumed(tmp_path):
    (tmp_path / MANIFEST).write_text(json.dumps({"complete": False, "runs": {},
                                                 "files": []}))
    prepare_output_dir(tmp_path, resume=True)


@pytest.mark.parametrize("run_id, safe", [
    ("line-0007_2026.11.23", True), ("../../etc", False), (".hidden", False), ("", False),
    ("a/b", False), ("x" * 300, False), ("sp ace", False)])
def test_run_ids_become_safe_folder_names(run_id, safe):
    name = run_folder_name(run_id)
    assert (name == run_id) is safe
    assert name and "/" not in name and not name.startswith(".") and len(name) <= 110
    assert run_folder_name(run_id) == name             # stable
