"""envs.sampler.ProblemSampler: a problem of the stream that exceeds the padding is redrawn
(counted), the stream is unchanged wherever it fits, and a source that never fits is a one-line
error naming the option."""

from __future__ import annotations

import pytest

from envs.observation import Dimensions, fits
from envs.sampler import ProblemSampler
from popbench.errors import ValueRangeError
from popbench.problems.synthetic import make_problem


def source(seed: int):  # noqa: ANN201
    """Problems whose size depends on the seed: 20 or 40 poses per robot."""
    return make_problem(2, "V2", 20 if seed % 3 else 40, seed=seed % 1000)


def test_a_problem_that_exceeds_the_padding_is_redrawn_and_counted() -> None:
    small = Dimensions.of([source(1)], margin=1.2)  # a 20-poses problem and a margin
    free, bounded = ProblemSampler(source, 2, seed=5), ProblemSampler(source, 2, 5, small)
    skipped = 0
    for _ in range(12):
        for element in range(2):
            unbounded, drawn = free.draw(element), bounded.draw(element)
            assert fits(drawn, small)
            if fits(unbounded, small):  # the stream is unchanged where it fits
                assert drawn.graph.name == unbounded.graph.name
            else:
                skipped += 1
    assert skipped > 0 and bounded.redrawn >= skipped


def test_a_source_that_never_fits_is_an_error_naming_the_option() -> None:
    tiny = Dimensions(vertices=4, edges=4, degree=4)
    with pytest.raises(ValueRangeError, match="max_vertices"):
        ProblemSampler(source, 1, 0, tiny).draw(0)
