"""Points in polygons (zones, walkable areas) with the border inside, and polygons that cross themselves."""
import numpy as np

from pcdet_memslidar.geometry.polygon import points_in_polygon, self_intersection

SQUARE = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])


def test_points_in_polygon_with_the_border_inside():
    points = np.array([[1, 1], [0, 0], [2, 1], [1, 2], [2.0000001, 1], [-1e-9, 1], [3, 3], [1, -0.5]])
    assert points_in_polygon(points, SQUARE).tolist() == [True, True, True, True, False, False, False, False]


def test_points_in_polygon_keeps_the_shape_of_its_points():
    paths = np.array([[[1, 1], [3, 3], [2, 2]], [[0.5, 0.5], [1.5, 1.5], [-1, 0]]])  # (people, samples, 2)
    assert points_in_polygon(paths, SQUARE).tolist() == [[True, False, True], [True, True, False]]


def test_a_concave_polygon():
    u_shape = np.array([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]], dtype=float)
    points = np.array([[0.5, 2.0], [1.5, 2.0], [2.5, 2.0], [1.5, 0.5], [1.5, 1.0]])
    assert points_in_polygon(points, u_shape).tolist() == [True, False, True, True, True]


def test_self_intersection_names_the_edges():
    bow_tie = np.array([[0, 0], [2, 2], [2, 0], [0, 2]], dtype=float)
    assert self_intersection(bow_tie) == (0, 2)
    assert self_intersection(SQUARE) is None
    touching = np.array([[0, 0], [4, 0], [4, 4], [2, 0], [0, 4]], dtype=float)  # vertex 4 lies on edge 1
    assert self_intersection(touching) is not None
