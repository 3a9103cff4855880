"""The experiments' plot helpers: no series hidden under an identical one, no colliding tick labels."""

from __future__ import annotations

from experiments.plots import merge_identical, spaced


def test_identical_series_are_drawn_once_under_both_names():
    merged = merge_identical({"a": ([1, 2], [0, 0]), "b": ([1, 3], [0, 0]), "c": ([1, 2], [0, 0])})
    assert merged == {"b": ([1, 3], [0, 0]), "a = c": ([1, 2], [0, 0])}
    assert merge_identical({"x": [1.0], "y": [1.0], "z": [1.0]}) == {"x = y = z": [1.0]}


def test_ticks_whose_labels_would_collide_are_dropped():
    epochs = [1, 2, 5, 10, 20, 30, 40, 60, 80, 100, 120]
    assert spaced(epochs, log=True) == [1, 2, 5, 10, 20, 30, 60, 100]
    assert spaced([25, 50, 100, 200, 400], log=True) == [25, 50, 100, 200, 400]
    assert spaced([2, 3, 4, 6, 8], log=False) == [2, 3, 4, 6, 8]
    assert spaced([0, 1, 100], log=False) == [0, 100]
