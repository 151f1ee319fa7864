"""The one atomic write: a file appears whole or not at all, flushed to disk before it replaces the old one."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from ilcsan import files


def _record_fsyncs(monkeypatch) -> list[int]:
    calls: list[int] = []
    real = os.fsync
    monkeypatch.setattr(files.os, "fsync", lambda descriptor: (calls.append(descriptor), real(descriptor))[1])
    return calls


@pytest.mark.parametrize("writer", ["bytes", "file"])
def test_atomic_writes_flush_to_disk_then_replace(tmp_path: Path, monkeypatch, writer: str) -> None:
    target = tmp_path / "sub" / "result.json"
    target.parent.mkdir()
    target.write_text("old")
    fsyncs = _record_fsyncs(monkeypatch)
    if writer == "bytes":
        files.atomic_write_bytes(target, b"new")
    else:
        files.atomic_write_file(target, lambda temporary: Path(temporary).write_text("new"))
    assert target.read_text() == "new"
    assert len(fsyncs) == 1, "the temporary file is flushed to disk before the rename"
    assert [p.name for p in target.parent.iterdir()] == ["result.json"], "no temporary file is left"


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "curves.png"
    target.write_text("old")

    def fail(temporary: str) -> None:
        Path(temporary).write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        files.atomic_write_file(target, fail)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["curves.png"]


def test_json_files_read_back_as_written_with_short_lists_on_one_line(tmp_path: Path) -> None:
    """config.json and the other JSON files: what is read back equals what was written (keys sorted, tuples as
    lists), and a list of numbers, or of lists of numbers (a bf16 run's product shapes), is one line."""
    import json

    data = {"b": {"hidden": (256, 256), "empty": [], "none": {}}, "a": 1.5, "name": "ILC-SAN", "flag": None,
            "matmul_path": {"bf16_products": [[[1, 5, 3760], [1, 256, 3760]], [[2, 100, 256], [2, 256, 256]]]},
            "segments": [{"step": 0, "cpu": "Intel"}, {"step": 400000, "cpu": "AMD"}]}
    path = tmp_path / "config.json"
    files.atomic_write_json(path, data)
    text = path.read_text()
    assert json.loads(text) == json.loads(json.dumps(data)), "the file reads back as the data"
    lines = text.splitlines()
    assert '    "hidden": [256, 256],' in lines
    assert '      [[1, 5, 3760], [1, 256, 3760]],' in lines, "each product's shapes on a line of their own"
    keys = [line.split('"')[1] for line in lines if line.startswith('  "')]
    assert keys == sorted(keys) == ["a", "b", "flag", "matmul_path", "name", "segments"]
    assert text.endswith("}\n") and '"step": 400000' in text, "objects inside lists keep one key per line"
