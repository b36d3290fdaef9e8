"""The benchmark's rows run and print (their figures are read from `make benchmark`, never
asserted: a timed unit test would measure the machine, not the code)."""

from flock_torchrl.report.benchmark import format_rows, learner_rows


def test_the_update_rows_compare_eager_compiled_and_vectorised_kernels():
    rows = learner_rows(batches=((128, "paper"),), updates=2, repeat=1)
    names = [row.what for row in rows]
    assert names == ["SAC updates, batch 128 UAV transitions (paper; eager vs previous)",
                     "SAC updates, batch 128 UAV transitions (paper; compiled vs previous)",
                     "SAC updates, batch 128 (paper; scalar vs vectorised compiled kernels)"]
    assert all(row.ours > 0 and row.baseline > 0 for row in rows)
    assert "scalar vs vectorised" in format_rows(rows)
