"""A whole map saved to one file and loaded back exactly."""

import numpy as np
import pytest
from conftest import mapped

from vmp.errors import InputError
from vmp.mapfile import load_map, save_map


def test_map_file_round_trip_is_exact(tmp_path):
    r = mapped("lab", scans=200)
    p = r.pipeline
    save_map(tmp_path / "m.vmpmap", p.map, p.milestones, p.back.graph, {"note": "test"},
             r.trajectory)
    back = load_map(tmp_path / "m.vmpmap")
    for name in ("end_points", "packed_hits", "rel_poses", "segments", "stamps"):
        a, b = getattr(p.map, name), getattr(back.map, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert back.map.segment_anchor == p.map.segment_anchor
    np.testing.assert_array_equal(back.milestones.poses, p.milestones.poses)
    np.testing.assert_array_equal(back.trajectory, r.trajectory)
    assert [(e.i, e.j, e.kind) for e in back.graph.edges] == \
        [(e.i, e.j, e.kind) for e in p.back.graph.edges]
    np.testing.assert_array_equal(back.map.world_poses(back.milestones.poses), r.trajectory)


def test_a_file_that_is_no_map_is_refused_by_name(tmp_path):
    (tmp_path / "junk.vmpmap").write_bytes(b"not a map")
    with pytest.raises(InputError, match=r"junk\.vmpmap"):
        load_map(tmp_path / "junk.vmpmap")


def test_a_member_with_a_damaged_array_header_is_refused_in_one_line(tmp_path):
    """numpy reads an .npy header with Python's tokenizer: an unclosed bracket there raises
    tokenize.TokenError, which is no ValueError (bench/fuzz.py: 12 of 100,000 map cases)."""
    import io
    import zipfile

    from milestones.store import StoreError, load_milestones

    buf = io.BytesIO()
    np.save(buf, np.zeros(3))
    damaged = buf.getvalue().replace(b"'shape': (3,)", b"'shape': (3,'")
    for name in ("m.vmpmap", "m.npz"):
        with zipfile.ZipFile(tmp_path / name, "w") as z:
            z.writestr("header.npy", damaged)
    with pytest.raises(InputError, match=r"m\.vmpmap: not a readable") as err:
        load_map(tmp_path / "m.vmpmap")
    assert "\n" not in str(err.value)
    with pytest.raises(StoreError, match=r"m\.npz"):
        load_milestones(tmp_path / "m.npz")
