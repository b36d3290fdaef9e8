"""Host reads (what makes a GPU wait): the counter itself, the pending episode rows, and the
training loop's own code, which reads nothing per iteration."""

import pytest
import torch
from tensordict import TensorDict

from flock_torchrl.run.batches import EPISODE_METRICS, PendingEpisodes, episode_values
from benchmarks.counting import HostReads


def test_the_counter_sees_each_kind_of_read_and_no_arithmetic():
    x = torch.arange(6.0) - 2.5
    mask = x > 0
    with HostReads() as reads:
        torch.where(mask, x, -x).cumsum(0).amax()
        x[torch.tensor([1, 2])]            # an integer index reads nothing
    assert reads.total == 0
    with HostReads() as reads:
        bool(mask.any())
        x.sum().item()
        x[mask]
        mask.nonzero()
        torch.equal(x, x)
        torch.unique(x)
    assert reads.total == 6
    assert {op for op, _ in reads.counts} == {"_local_scalar_dense", "index", "nonzero", "equal", "_unique2"}
    assert all(place.startswith("tests/") or place == "elsewhere" for _, place in reads.counts)


def test_the_counter_notes_tensors_made_from_python_numbers():
    x = torch.ones(3)
    with HostReads() as reads:
        torch.tensor([1.0, 2.0])
        x.new_tensor([0.5])
        torch.zeros_like(x) + 1.0  # made on the device: not noted
    assert reads.total == 0 and sum(reads.made.values()) == 2 and all(p == "elsewhere" for p in reads.made), reads.made


def test_kernels_are_counted_apart_from_views_and_by_whether_a_graph_holds_them():
    from flock_torchrl.capture import captured

    x = torch.ones(4, 3)
    inside = captured(lambda t: (t * 2).sum(0), torch.device("cpu"))
    with HostReads(launches=True) as reads:
        y = x.reshape(12)                                      # a view: no kernel
        z = x + 1.0                                            # a kernel, outside any graph
        z.add_(1.0)                                            # in place: a kernel too
        inside(x)  # inside a captured function: its two kernels, and (on a CPU) the wrapper's copy of x
    assert y.data_ptr() == x.data_ptr()
    assert sum(reads.launched.values()) == 2 and reads.launched_in_graphs == 3, (reads.launched,
                                                                                reads.launched_in_graphs)
    assert reads.total == 0 and not reads.made


def test_reads_inside_a_captured_step_are_counted_apart():
    mask = torch.tensor([True, False])

    def _captured_step():
        return bool(mask.any())

    with HostReads() as reads:
        _captured_step()
        bool(mask.all())
    assert reads.total == 1 and sum(reads.in_captured.values()) == 1
    assert "(captured)" in reads.table()


def _batch(done: list[list[bool]], first: float) -> TensorDict:
    """A collector batch ``[worlds, steps]`` whose episode metrics count up from ``first``."""
    worlds, steps = len(done), len(done[0])
    count = worlds * steps
    episode = {k: (first + i + torch.arange(count, dtype=torch.float64)).reshape(worlds, steps).float()
               for i, k in enumerate(EPISODE_METRICS)}
    return TensorDict({"next": {"done": torch.tensor(done).unsqueeze(-1),
                                "episode": TensorDict(episode, [worlds, steps])}}, [worlds, steps])


def test_pending_episodes_give_the_rows_boolean_indexing_gives_in_order():
    batches = [_batch([[False, True, False], [True, False, True]], 0.0),
               _batch([[False, False, False], [False, False, False]], 100.0),
               _batch([[False, False, True], [False, False, False]], 200.0)]
    pending = PendingEpisodes()
    with HostReads() as reads:
        for frames, batch in zip((6, 12, 18), batches):
            pending.add(batch, frames, source=frames // 6)
    assert reads.total == 0 and pending.slots == 18
    finished = pending.flush()
    assert [f.frames for f in finished] == [6, 18] and [f.source for f in finished] == [1, 3]
    assert finished[0].worlds == [0, 1, 1] and finished[1].worlds == [0]
    for f, batch in zip(finished, (batches[0], batches[2])):
        done = batch.get(("next", "done")).squeeze(-1)
        assert f.values == episode_values(batch.get(("next", "episode"))[done]).tolist()
    assert pending.slots == 0 and pending.flush() == []


def test_a_pending_batch_is_a_copy_of_what_the_collector_may_reuse():
    batch = _batch([[True]], 5.0)
    pending = PendingEpisodes()
    pending.add(batch, 1)
    batch.get(("next", "done")).zero_()
    batch.get(("next", "episode"))["return"].fill_(-1.0)
    (finished,) = pending.flush()
    assert finished.values[0][0] == 5.0


@pytest.mark.slow
@pytest.mark.parametrize("members", [1, 2])
def test_the_training_loop_reads_nothing_per_iteration(members):
    """Collection, the replay buffer, sampling, the update and the episode bookkeeping of a solo
    run and a population read no tensor on the host between logs. Without a reserve of fresh
    worlds the resets read (TorchRL's ``maybe_reset`` and the worlds drawn anew); with one
    (``reset_pool``, large enough here not to be refilled while counted) nothing does."""
    from benchmarks.host_reads import count_reads

    overrides = ("scenario.max_steps=8",)
    reads, iterations = count_reads("tiny", members, iterations=12, overrides=overrides)
    assert iterations == 12
    loop = [place for _, place in reads.counts if not place.startswith(("flock_torchrl/world/", "torchrl/envs/"))]
    assert not loop, reads.table()
    assert reads.total >= 2 * 12, reads.table()  # the resets' reads, at least TorchRL's two per step
    # tiny: 4 worlds (per member), 4 steps per batch; 22 iterations before counting, 12 counted.
    reads, iterations = count_reads("tiny", members, iterations=12, overrides=(*overrides, "reset_pool=600"))
    assert iterations == 12 and reads.total == 0, reads.table()
    # Nor does it make a tensor from Python numbers (on a GPU a copy from the host): TorchRL's
    # reset pads what it does not write with one per key and call; the reserve's hand-out does not.
    assert not reads.made, reads.made


@pytest.mark.parametrize("profile, waits", [(False, 0), (True, 2 * 3)])
def test_the_time_split_waits_for_the_device_only_where_it_is_read(profile, waits):
    """On CUDA (simulated on a CPU without one) the time split records events around its blocks
    and reads them when settled, where the loop reads the host anyway: no wait per block; with
    ``profile`` it synchronises at each block's start and end instead. On a CPU it never waits."""
    from simulated_cuda import simulated_cuda

    from flock_torchrl.run.timing import TimeSplit

    context = simulated_cuda() if not torch.cuda.is_available() else torch.no_grad()
    with context:
        split = TimeSplit(device="cuda", profile=profile)
        with HostReads() as reads:
            for bucket in ("collection", "update", "update"):
                with split.timer(bucket):
                    torch.ones(3, device="cuda").sum()
        per_block = sum(n for (op, _), n in reads.counts.items() if op == "synchronize")
        assert per_block == waits, reads.table()
        with HostReads() as reads:
            settled = split.settle()
        assert sum(n for (op, _), n in reads.counts.items() if op == "synchronize") == (0 if profile else 1)
        assert settled["update"] > 0 and settled["collection"] > 0 and not split.events
    cpu = TimeSplit()
    with HostReads() as reads, cpu.timer("update"):
        torch.ones(3).sum()
    assert reads.total == 0 and cpu["update"] > 0
