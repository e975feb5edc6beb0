"""benchmarks/mutation_score.py: its mutations still point at the code they mutate."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

import mutation_score

SRC = Path(__file__).resolve().parents[1] / "src"


def test_every_mutation_snippet_occurs_exactly_once() -> None:
    # A refactor that moves a mutated line breaks the benchmark only when someone runs it;
    # this names the stale mutation at once.
    mutation_score.check_mutations(SRC, mutation_score.MUTATIONS)


def test_a_stale_mutation_is_named() -> None:
    stale = mutation_score.MUTATIONS[0]
    edit = replace(stale.edits[0], original=stale.edits[0].original + "  # moved")
    moved = replace(stale, edits=(edit,))
    with pytest.raises(SystemExit, match=stale.name):
        mutation_score.check_mutations(SRC, (moved,))
