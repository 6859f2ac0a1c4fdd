"""Exports of the vector map: occupancy grid (map_server, PNG), contours of free space."""

import json
import math
import zlib

import numpy as np
import pytest
import shapely

from vmp.errors import InputError
from vmp.export import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    coverage,
    free_space_contours,
    occupancy_grid,
    read_ros_map,
    write_png,
    write_ros_map,
)


def star_polygons(n=30, seed=0):
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, (n, 36)), axis=1)
    r = rng.uniform(0.5, 3, (n, 36))
    c = rng.uniform(0, 10, (n, 1, 2))
    return c + np.stack([r * np.cos(ang), r * np.sin(ang)], -1)


@pytest.mark.parametrize(("origin", "shape"), [((-4.0, -4.0), (360, 380)),
                                               # polygons cut by every side of the grid
                                               ((1.0, 2.0), (90, 110))])
def test_rasterised_fill_matches_shapely_cell_by_cell(origin, shape):
    polys = star_polygons()
    res = 0.05
    cov = coverage(polys, origin, res, shape)
    xs = origin[0] + (np.arange(shape[1]) + 0.5) * res
    ys = origin[1] + (np.arange(shape[0]) + 0.5) * res
    X, Y = np.meshgrid(xs, ys)
    ref = sum(shapely.contains_xy(shapely.Polygon(p), X, Y).astype(int) for p in polys)
    np.testing.assert_array_equal(cov, ref)


def square_room_grid():
    # A 4 x 2 m room seen from its centre: one polygon, hits along the walls.
    poly = np.array([[[0.0, 0.0], [4.0, 0.0], [4.0, 2.0], [0.0, 2.0]]])
    t = np.linspace(0, 1, 400)
    hits = np.vstack([np.column_stack([4 * t, 0 * t]), np.column_stack([4 * t, 0 * t + 2])])
    return occupancy_grid(poly, hits, 0.1, margin=0.3)


def test_grid_values_and_orientation():
    g = square_room_grid()
    assert set(np.unique(g.cells)) <= {OCCUPIED, FREE, UNKNOWN}
    # Row 0 is the bottom (lowest y): the wall at y = 0 lies 3 rows above the 0.3 m margin.
    np.testing.assert_allclose(g.origin, (-0.3, -0.3), atol=1e-9)
    row_wall = round((0.0 - g.origin[1]) / g.resolution)
    assert (g.cells[row_wall, 5:40] == OCCUPIED).mean() > 0.9
    assert g.cells[row_wall + 10, 20] == FREE
    assert g.cells[0, 0] == UNKNOWN


def test_ros_map_round_trip_and_file_form(tmp_path):
    g = square_room_grid()
    pgm = write_ros_map(tmp_path / "map.yaml", g)
    raw = pgm.read_bytes()
    assert raw.startswith(b"P5\n")
    back = read_ros_map(tmp_path / "map.yaml")
    np.testing.assert_array_equal(back.cells, g.cells)
    assert back.resolution == g.resolution
    np.testing.assert_allclose(back.origin, g.origin, rtol=0, atol=1e-9)  # to the nanometre
    assert "- -0.3\n" in (tmp_path / "map.yaml").read_text()  # as a person writes it
    # The image's first row is the top of the map.
    H, W = g.shape
    first_row = np.frombuffer(raw[-H * W:][:W], dtype=np.uint8)
    np.testing.assert_array_equal(first_row, g.cells[-1])
    meta = (tmp_path / "map.yaml").read_text()
    for key in ("image: map.pgm", "resolution: 0.1", "negate: 0", "occupied_thresh: 0.65",
                "free_thresh: 0.196"):
        assert key in meta
    with pytest.raises(InputError, match=r"\.yaml"):
        write_ros_map(tmp_path / "map.txt", g)


def test_png_holds_the_grid(tmp_path):
    g = square_room_grid()
    write_png(tmp_path / "g.png", g)
    data = (tmp_path / "g.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    idat = data[data.index(b"IDAT") + 4:data.index(b"IEND") - 8]
    rows = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(g.shape[0], -1)
    np.testing.assert_array_equal(rows[:, 1:], g.cells[::-1])


def test_contours_are_the_union_of_free_space():
    polys = np.array([[[0, 0], [2, 0], [2, 2], [0, 2]], [[1, 1], [3, 1], [3, 3], [1, 3]]],
                     dtype=float)
    geom = free_space_contours(polys)
    assert math.isclose(geom.area, 7.0, rel_tol=1e-6)
    assert json.loads(shapely.to_geojson(geom))["type"] == "Polygon"


def test_contours_do_not_depend_on_the_threads_or_the_machine(monkeypatch):
    # A map's contours must be the same on any machine and in a batch worker that unites
    # with one thread: the scans are grouped the same way however many threads share them.
    polys = star_polygons(1800, seed=3)
    polys[:, :, 0] += np.linspace(0, 60, len(polys))[:, None]  # scans along a path
    one = free_space_contours(polys, threads=1)
    assert one.equals_exact(free_space_contours(polys, threads=3), 0.0)
    for cores in (1, 4):
        monkeypatch.setattr("os.cpu_count", lambda cores=cores: cores)
        assert one.equals_exact(free_space_contours(polys), 0.0)


def test_a_thin_scan_polygon_is_not_lost_to_the_simplification():
    # A scan taken about a centimetre from a wall, one beam a metre out through a gap (found
    # by a random search over star polygons): Douglas-Peucker without topology would reduce
    # it to nothing.
    ring = np.array([[0.0, 0.0], [-0.0056, -0.0127], [-0.0059, -0.0133], [-0.0005, -0.0146],
                     [0.3093, -0.9891], [0.0064, -0.0063], [0.018, -0.0163], [0.0069, -0.0047],
                     [0.0085, -0.0039], [0.0177, -0.0074], [0.0138, 0.0036], [0.0094, 0.0034],
                     [0.0027, 0.0187]])
    beside = np.array([[5.0, 5.0], [6.0, 5.0], [6.0, 6.0]] + [[5.0, 6.0]] * 10)
    geom = free_space_contours(np.stack([ring, beside]))
    assert geom.area > 0.5 + 0.004
    assert geom.intersects(shapely.LineString([(0.1, -0.6), (0.3, -0.6)]))


# --- metrics ----------------------------------------------------------------------------------

def literal_ate(est, ref):
    """ATE by brute force: the best rotation on a fine grid, translation by the centroids."""
    best = np.inf
    for th in np.linspace(-np.pi, np.pi, 20001):
        c, s = np.cos(th), np.sin(th)
        p = est[:, :2] @ np.array([[c, s], [-s, c]])
        t = ref[:, :2].mean(axis=0) - p.mean(axis=0)
        err = np.sqrt(np.mean(np.sum((p + t - ref[:, :2]) ** 2, axis=1)))
        best = min(best, err)
    return best


def test_contours_survive_a_failed_snap_rounding_union(monkeypatch):
    """GEOS's snapped overlay can throw a TopologyException on nearly coincident edges (the
    Radish freiburg-079 log): the union is then made unsnapped and snapped afterwards."""
    polys = star_polygons(n=20)
    want = free_space_contours(polys)
    real = shapely.union_all

    def failing_when_snapped(geoms, grid_size=None, **kwargs):
        if grid_size is not None:
            raise shapely.errors.GEOSException("TopologyException: Ring edge missing at 1 2")
        return real(geoms, **kwargs)

    monkeypatch.setattr(shapely, "union_all", failing_when_snapped)
    got = free_space_contours(polys)
    assert got.is_valid and not got.is_empty
    assert abs(got.area - want.area) < 1e-3 * want.area
    assert shapely.set_precision(got, 0.01).equals(got)  # snapped to the 1 cm grid
