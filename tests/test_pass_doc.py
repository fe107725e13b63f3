"""docs/passes.md's example runs as written and gives the parts it describes."""



import numpy as np
from runs import run_doc_example



def test_the_pass_example_runs_as_written():
    scope, printed = run_doc_example("passes.md")
    result = scope["result"]
    assert len(result.queries) == 2 and all(q > 0 for q in result.queries)
    # per-sample data of the "none" target, one image per lens view (tests/test_targets.py checks their values)
    t = result.sample_data["time"]
    assert t.shape == (48, 64, 16, 2)
    left, right = result.images["eyes"]
    assert left.shape == right.shape == result.image.shape
    # the appended records: one per shaded sample, inside the frame and the shutter
    records = result.append.records
    assert np.all((records[:, 0] >= 0) & (records[:, 0] < 64) & (records[:, 1] >= 0) & (records[:, 1] < 48))
    assert np.all((records[:, 4] >= 0) & (records[:, 4] <= 1)) and result.append.overflow == 0
    assert "records appended" in printed
