"""The beam tracer against the one-point reference, and a roof that stops the beam."""

import numpy as np

from fwcore.studies.forest_trace import TreeIndex, leaf_density, trace_leaf_area

# x, y, crown centre z, half depth, radius, base density, top factor, shell density
TREES = np.array([[0.0, 0.0, 115.0, 5.0, 3.0, 0.2, 2.0, 1.5],
                  [4.0, 1.0, 112.0, 3.0, 2.5, 0.1, 1.0, 0.8]])


def test_the_kernel_meets_the_density_of_the_reference_at_every_step():
    index = TreeIndex.of(TREES, 0.1)
    rng = np.random.default_rng(0)
    n, step, steps = 200, 0.25, 100
    hit = np.column_stack([rng.uniform(-4, 7, n), rng.uniform(-4, 4, n), np.full(n, 100.0)])
    angle = rng.uniform(-0.2, 0.2, n)
    beam = np.column_stack([np.zeros(n), np.sin(angle), -np.cos(angle)])
    lad, roof = trace_leaf_area(hit, beam, step, steps, index, np.zeros((0, 5)))
    assert np.isnan(roof).all() and lad.max() > 0
    for p in range(0, n, 17):
        for k in range(0, steps, 7):
            up = (k + 0.5) * step
            point = hit[p] - beam[p] * up / np.cos(angle[p])
            assert lad[p, k] == leaf_density(TREES, 0.1, *point)


def test_a_roof_stops_the_beam_at_its_height():
    index = TreeIndex.of(TREES, 0.1)
    building = np.array([[20.0, 20.0, 30.0, 30.0, 108.0]])
    hit = np.array([[25.0, 25.0, 100.0], [0.0, 0.0, 100.0]])
    beam = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    lad, roof = trace_leaf_area(hit, beam, 0.25, 100, index, building)
    assert roof[0] == 8.0 and np.isnan(roof[1])
    assert not lad[0].any()
    # the vertical through the first crown's centre: its base density to the shell, then the shell
    column = lad[1]
    assert not column[:40].any() and not column[80:].any() and column[40:80].all()  # the crown: 110 to 120 m
    assert column[79] == 1.5 and np.isclose(column[40], 1.5)  # the shell at its top and its bottom
