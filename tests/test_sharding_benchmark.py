"""experiments/benchmarks/sharding.py: the physics calls' concurrency is their summed time over the length of
the union of their intervals (1 when the devices take turns, N when N compute at once)."""

import pytest

from experiments.benchmarks.sharding import union_length


@pytest.mark.parametrize(
    ("intervals", "length"),
    [
        ([(0.0, 1.0), (1.0, 2.0)], 2.0),  # taking turns: concurrency 2 / 2 = 1
        ([(0.0, 1.0), (0.0, 1.0)], 1.0),  # at once: 2 / 1 = 2
        ([(0.0, 2.0), (0.5, 1.0), (3.0, 4.0)], 3.0),  # one inside another, then a gap
        ([(1.0, 3.0), (0.0, 2.0)], 3.0),  # out of order, overlapping
        ([], 0.0),
    ],
)
def test_union_length(intervals, length):
    assert union_length(intervals) == pytest.approx(length)
