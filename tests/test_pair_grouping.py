"""Pair grouping in linear time (issue 26): the same groups as scanning what is left for every
draw (the former, quadratic algorithm, kept here as the reference)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from fgcal.calibration.formulations.pairs import PREFERENCE, _grouped, category


def _scanning(order, labels_of, partner, size, rng):
    """The former algorithm: every draw scans the images left."""
    remaining, groups = list(order), []
    while remaining:
        group = [remaining.pop(0)]
        while len(group) < size and remaining:
            previous = labels_of[group[-1]]
            choice = None
            for wanted in PREFERENCE[partner]:
                options = [k for k in remaining if category(previous, labels_of[k]) == wanted]
                if options:
                    choice = options[int(rng.integers(len(options)))]
                    break
            if choice is None:
                choice = remaining[int(rng.integers(len(remaining)))]
            remaining.remove(choice)
            group.append(choice)
        groups.append(group)
    return groups


@pytest.mark.parametrize("partner", sorted(PREFERENCE))
@pytest.mark.parametrize("size", [2, 3, 5])
def test_linear_grouping_draws_the_same_groups(partner, size):
    rng = np.random.default_rng(size)
    n = 400
    objects, sides = ["A", "B", "C"], ["x", "y", "z", "w"]
    labels_of = {j: (str(rng.choice(objects[: 1 + size % 3])), str(rng.choice(sides))) for j in range(1000, 1000 + n)}
    order = [int(j) for j in rng.permutation(sorted(labels_of))]
    settings = SimpleNamespace(pairs=SimpleNamespace(partner=partner, group_images=size))
    mine = _grouped(order, [labels_of[j] for j in order], settings, np.random.default_rng(7))
    reference = _scanning(order, labels_of, partner, size, np.random.default_rng(7))
    assert mine == reference
    assert sorted(j for g in mine for j in g) == sorted(labels_of)
