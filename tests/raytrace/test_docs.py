"""Docstring examples run (pytest --doctest-modules would also import the benchmarks)."""

import doctest

import raytrace
import raytrace.scene


def test_package_docstring_example_runs():
    result = doctest.testmod(raytrace)
    assert result.attempted >= 3 and result.failed == 0


def test_scene_docstring_example_runs():
    result = doctest.testmod(raytrace.scene)
    assert result.attempted >= 4 and result.failed == 0
