"""units/made_ahead.py: what units make of a region's samples ahead, held by sample set."""

from __future__ import annotations

from pipeline_sim.sampling import make_samples
from units.made_ahead import MadeAhead


def test_made_ahead_hands_out_a_sets_own_and_drops_those_of_earlier_rows():
    """``MadeAhead``: a set's held value is taken once; taking a set's drops (and returns) those of sets
    of earlier rows, keeps those of later rows, and says whether any is left."""
    sets = [make_samples(8, 64, 4, 1, lens=False, motion=True, rows=(r0, r0 + 16)) for r0 in (0, 16, 32, 48)]
    held = MadeAhead()
    for i in (0, 1, 3):
        held.hold(sets[i], f"made {i}")
    assert len(held) == 3
    assert held.take(sets[1]) == ("made 1", ["made 0"], True)  # 0 passed; 3 still ahead
    assert held.take(sets[2]) == (None, [], True)  # nothing held for 2
    assert held.take(sets[3]) == ("made 3", [], False)
    assert held.take(sets[3]) == (None, [], False) and len(held) == 0
