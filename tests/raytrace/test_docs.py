"""Docstring examples run (pytest --doctest-modules would also import the benchmarks)."""

import doctest

import raytrace


def test_package_docstring_example_runs():
    result = doctest.testmod(raytrace)
    assert result.attempted >= 3 and result.failed == 0
