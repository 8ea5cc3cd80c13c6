"""PCD headers and bodies that disagree: each an error naming the file and both numbers (reading
either number silently gives a scan, and labels, of the wrong length)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from dsnet_core.errors import PointFileFormatError
from dsnet_core.io.folder import FolderReader
from dsnet_core.io.pcd import read_pcd

FIELDS = ("x", "y", "z", "intensity")


def _cloud(n: int, seed: int = 0) -> list[np.ndarray]:
    """Points on a 0.5 m grid, intensity in quarters: exact in ASCII and compressible (pypcd4 writes
    ``binary`` where LZF would not shrink the block)."""
    rng = np.random.default_rng(seed)
    xyz = (rng.integers(-40, 40, (n, 3)) * 0.5).astype(np.float32)
    return [xyz[:, 0], xyz[:, 1], xyz[:, 2], (rng.integers(0, 5, n) / 4).astype(np.float32)]


def _write(path, n: int, encoding: str) -> np.ndarray:
    """A PCD of ``n`` points written by pypcd4; returns the points (n, 4)."""
    from pypcd4 import Encoding, PointCloud

    cols = _cloud(n)
    PointCloud.from_points(cols, FIELDS, [np.float32] * 4).save(path, encoding=Encoding(encoding))
    assert f"DATA {encoding}\n".encode() in path.read_bytes()
    return np.column_stack(cols)


def _set_header(path, **values: int) -> None:
    """Rewrite header lines (``POINTS=6111``) of a PCD in place."""
    raw = path.read_bytes()
    end = raw.index(b"DATA")
    header = raw[:end].decode()
    for key, value in values.items():
        header, count = re.subn(rf"^{key} .*$", f"{key} {value}", header, flags=re.M)
        assert count == 1, key
    path.write_bytes(header.encode() + raw[end:])


def _error(path) -> str:
    with pytest.raises(PointFileFormatError) as err:
        FolderReader(path.parent).scan(FolderReader(path.parent).frames(path.parent.name)[0])
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg and "Traceback" not in msg
    return msg


@pytest.mark.parametrize("encoding", ["binary", "binary_compressed", "ascii"])
def test_points_that_disagree_with_width_times_height(tmp_path, encoding):
    # the file: POINTS 6111 while WIDTH and the body hold 12222 (it read 6111 points, exit 0)
    path = tmp_path / "scans" / "a.pcd"
    path.parent.mkdir()
    pts = _write(path, 12222, encoding)
    assert read_pcd(path).shape == (12222,)
    assert np.array_equal(FolderReader(path.parent).scan(FolderReader(path.parent).frames("scans")[0]), pts)
    _set_header(path, POINTS=6111)
    msg = _error(path)
    assert "header says POINTS 6111 but WIDTH × HEIGHT = 12222 × 1 = 12222" in msg


def test_a_binary_body_that_holds_more_points_than_the_header(tmp_path):
    path = tmp_path / "scans" / "a.pcd"
    path.parent.mkdir()
    _write(path, 12222, "binary")
    _set_header(path, POINTS=6111, WIDTH=6111)
    assert "binary body holds 12222 points (195552 bytes), the header says POINTS 6111" in _error(path)
    path.write_bytes(path.read_bytes() + b"\n")  # not a whole point more
    assert "binary body has 195553 bytes, the header says POINTS 6111 (6111 × 16 = 97776 bytes)" in _error(
        path
    )


def test_an_ascii_body_with_more_rows_than_the_header(tmp_path):
    # the second file: an ASCII PCD whose POINTS is 100 below its row count
    path = tmp_path / "scans" / "a.pcd"
    path.parent.mkdir()
    _write(path, 1000, "ascii")
    _set_header(path, POINTS=900, WIDTH=900)
    assert "ascii body holds 1000 rows, the header says POINTS 900 (of 4 values each)" in _error(path)
    # rows of five values where the fields make four: the message counts values
    _write(path, 1000, "ascii")
    raw = path.read_bytes()
    head, body = raw.split(b"DATA ascii\n")
    body = b"\n".join(line + b" 7" for line in body.splitlines()) + b"\n"
    path.write_bytes(head + b"DATA ascii\n" + body)
    assert (
        "ascii body holds 5000 values in 1000 rows, the header says POINTS 1000 (of 4 values each)"
        in _error(path)
    )
    _write(path, 1000, "ascii")
    _set_header(path, POINTS=1100, WIDTH=1100)
    assert "ascii body has 4000 values, the header promises 1100 points × 4: truncated" in _error(path)


def test_a_compressed_block_that_unpacks_to_another_count(tmp_path):
    path = tmp_path / "scans" / "a.pcd"
    path.parent.mkdir()
    _write(path, 12222, "binary_compressed")
    _set_header(path, POINTS=6111, WIDTH=6111)
    msg = _error(path)
    assert "compressed block unpacks to 195552 bytes (12222 points), the header says POINTS 6111" in msg
    _write(path, 12222, "binary_compressed")
    assert b"DATA binary_compressed" in path.read_bytes()
    path.write_bytes(path.read_bytes() + b"\0" * 5)
    assert re.search(r"body has 5 bytes after its compressed block of \d+ bytes", _error(path))


def test_header_counts_that_are_missing_or_not_counts(tmp_path):
    path = tmp_path / "scans" / "a.pcd"
    path.parent.mkdir()
    pts = _write(path, 50, "binary")
    raw = path.read_bytes()
    path.write_bytes(re.sub(rb"POINTS 50\n", b"", raw))  # WIDTH × HEIGHT alone gives the count
    assert read_pcd(path).shape == (50,)
    path.write_bytes(re.sub(rb"WIDTH 50\nHEIGHT 1\n", b"", raw))  # POINTS alone too
    assert np.array_equal(FolderReader(path.parent).scan(FolderReader(path.parent).frames("scans")[0]), pts)
    path.write_bytes(re.sub(rb"WIDTH 50\nHEIGHT 1\n(.*\n)?POINTS 50\n", b"", raw))
    assert "header has neither POINTS nor WIDTH" in _error(path)
    path.write_bytes(raw.replace(b"POINTS 50", b"POINTS -50"))
    assert "header line POINTS '-50' is not a count" in _error(path)
    path.write_bytes(raw.replace(b"HEIGHT 1", b"HEIGHT 2"))
    assert "header says POINTS 50 but WIDTH × HEIGHT = 50 × 2 = 100" in _error(path)
