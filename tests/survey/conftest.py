"""Fixtures shared by the survey tests."""

from __future__ import annotations

import pytest

from survey.cli.main import main


@pytest.fixture(scope="session")
def tbm_mesh(tmp_path_factory):
    """make(edge_length_m) -> path of a 'tbm' preset tunnel written by the CLI (once per
    edge length and session; tests must not modify it)."""
    made = {}

    def make(edge_length_m: float):
        if edge_length_m not in made:
            out = tmp_path_factory.mktemp("tbm") / "tbm.ply"
            assert main(["tunnel", "-o", str(out), "--preset", "tbm", "--edge-length",
                         str(edge_length_m), "--quiet"]) == 0
            made[edge_length_m] = out
        return made[edge_length_m]

    return make
