import os

import pytest

from sb3_icrl.common.utils import atomic_write_bytes, atomic_write_json


def test_atomic_write_json_leaves_old_file_on_failure(tmp_path):
    path = tmp_path / "sub" / "result.json"
    atomic_write_json(path, {"a": 1})
    with pytest.raises(TypeError):
        atomic_write_json(path, {"a": object()})
    assert path.read_text() == '{"a": 1}'
    assert [name.name for name in path.parent.iterdir()] == ["result.json"], "no temporary file left behind"


def test_atomic_write_bytes_fails_half_way_without_damage(tmp_path):
    path = tmp_path / "data.bin"
    atomic_write_bytes(path, b"old")
    with pytest.raises(TypeError):
        atomic_write_bytes(path, "not bytes")  # type: ignore[arg-type]
    assert path.read_bytes() == b"old"
    assert [name.name for name in tmp_path.iterdir()] == ["data.bin"]
    assert oct(os.stat(path).st_mode & 0o777) == "0o644"
