"""Where code reads tensor values on the host: on a GPU each such read waits for the device
(a synchronisation), and none may sit inside a captured CUDA graph. A development tool of the
repository (the tests and the benchmarks count with it), not of the installed package.

:class:`HostReads` is a ``TorchDispatchMode`` that counts, by operator and by the line of
flock_torchrl, TorchRL or tensordict that asked, the operators whose result depends on tensor
values the host must see: ``.item()``, ``bool()``, ``int()`` and ``float()`` of a tensor
(``_local_scalar_dense``), ``nonzero``, indexing with a boolean mask, ``masked_select``,
``unique``, ``equal`` and ``allclose``, a copy from a CUDA tensor to the CPU, and one from the
CPU to CUDA unless non-blocking from pinned memory (torch waits for the stream after it). It sees
the first kinds on a CPU just as on a GPU (the copies only where there is CUDA), so the tests here
can hold a training iteration to none::

    with HostReads() as reads:
        ...
    print(reads.total, reads.table())

Reads inside a function that tensordict's ``CudaGraphModule`` records (the learners'
``_captured_step``) are counted apart, in ``in_captured``: on a GPU they run while the graph is
warmed up and recorded, and a replay never runs them (TorchRL's ``TanhNormal`` even skips its
argument checks while a graph records).

It also notes, in ``made``, the tensors made from Python numbers (``torch.tensor([...])``,
``new_tensor``: ``lift_fresh``): free on a CPU, but each a copy from the host on a GPU, which
waits and which a CUDA graph cannot record, so a step that makes one cannot be captured.

With ``launches=True`` it also counts the operators that launch a kernel on a GPU (all but
views, bare allocations and the reads): ``launched``, by the line of flock_torchrl or TorchRL
that asked, those outside every function tensordict's ``CudaGraphModule`` wraps (on a GPU each
is a launch the host pays for, one by one), and ``launched_in_graphs``, those inside (on a GPU
a replay launches them as one graph). A CPU runs the wrapped functions as they are, so the
count is the same here as there.

It also counts, in ``counts`` as operator ``synchronize``, the host's explicit waits for the device:
``torch.cuda.synchronize`` and a CUDA event's ``synchronize`` (flock_torchrl.run.timing's time
split settling its events, or waiting at every block with ``profile``), by the line that asked.

It cannot see ``Tensor.tolist()`` or ``.numpy()`` of a CPU tensor (they read memory without
dispatching an operator), nor what runs inside a compiled graph (it runs such code eagerly, as
the compiled paths' eager twins).
"""

from __future__ import annotations

import collections
import traceback
from typing import Any

import torch
from torch.utils._python_dispatch import TorchDispatchMode

aten = torch.ops.aten

# Operators whose output (a Python number, or a tensor whose shape depends on values) needs the
# values on the host.
_READING = {aten._local_scalar_dense, aten.is_nonzero, aten.nonzero, aten.masked_select, aten._unique2,
            aten.unique_dim, aten.unique_consecutive, aten.equal, aten.allclose, aten.nonzero_static}
# Indexing operators that read the values of a boolean index.
_INDEXING = {aten.index, aten.index_put, aten.index_put_, aten._index_put_impl_}
# The packages whose lines name a read (the first such frame, innermost first, is its place).
_PACKAGES = ("flock_torchrl/", "torchrl/", "tensordict/")


def _reads(func: Any, args: tuple, kwargs: dict) -> bool:
    packet = func.overloadpacket
    if packet in _READING:
        return packet is not aten.nonzero_static
    if packet in _INDEXING:
        indices = args[1] if len(args) > 1 else kwargs.get("indices", ())
        return any(isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in indices or ())
    if packet is aten._to_copy:
        source, target = args[0], kwargs.get("device")
        return (isinstance(source, torch.Tensor) and target is not None
                and _waits(source, torch.device(target), bool(kwargs.get("non_blocking", False))))
    if packet is aten.copy_:
        target, source = args[0], args[1]
        non_blocking = bool(args[2]) if len(args) > 2 else bool(kwargs.get("non_blocking", False))
        return isinstance(source, torch.Tensor) and _waits(source, target.device, non_blocking)
    return False


def _waits(source: torch.Tensor, target: torch.device, non_blocking: bool) -> bool:
    """Whether copying ``source`` to ``target`` waits for the device: CUDA to the CPU always; the
    CPU to CUDA unless from pinned memory without blocking (torch synchronises the stream after a
    blocking copy between them, and a copy from pageable memory is staged by the host)."""
    if source.device.type == "cuda" and target.type == "cpu":
        return True
    return source.device.type == "cpu" and target.type == "cuda" and not (non_blocking and source.is_pinned())


# The functions CudaGraphModule records (flock_torchrl.policies: the learners' whole update).
CAPTURED = ("_captured_step",)
# Allocations without a kernel, and the reads (a wait, not a launch).
_NO_KERNEL = {aten.empty, aten.empty_strided, aten._local_scalar_dense}


def _launches(func: Any) -> bool:
    """Whether ``func`` runs a kernel: not a view (an output aliasing an input without writing
    it), a bare allocation or a read of a value."""
    if func.overloadpacket in _NO_KERNEL:
        return False
    return not any(r.alias_info is not None and not r.alias_info.is_write for r in func._schema.returns)


def _in_graph(stack: traceback.StackSummary) -> bool:
    """Whether a frame of ``stack`` is a call through tensordict's ``CudaGraphModule``."""
    return any(frame.filename.replace("\\", "/").endswith("tensordict/nn/cudagraphs.py") for frame in stack)


def _place(stack: traceback.StackSummary, packages: tuple[str, ...] = _PACKAGES) -> str:
    """``package/file.py:line:function`` of the innermost frame in one of ``packages``
    (outside this module), or ``"elsewhere"``."""
    for frame in reversed(stack):
        name = frame.filename.replace("\\", "/")
        if name.endswith("benchmarks/counting.py"):
            continue
        for package in packages:
            at = name.rfind("/" + package)
            if at >= 0:
                return f"{name[at + 1:]}:{frame.lineno}:{frame.name}"
    return "elsewhere"


class HostReads(TorchDispatchMode):
    """Counts host reads of tensor values while active (what each count holds: the module's
    docstring): ``counts`` and ``in_captured`` by ``(operator, place)``, outside and inside
    :data:`CAPTURED` functions; ``made`` and ``launched`` by place."""

    def __init__(self, launches: bool = False) -> None:
        super().__init__()
        self.launches = launches
        self.launched: collections.Counter[str] = collections.Counter()
        self.launched_in_graphs = 0
        self.counts: collections.Counter[tuple[str, str]] = collections.Counter()
        self.in_captured: collections.Counter[tuple[str, str]] = collections.Counter()
        self.made: collections.Counter[str] = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        reads, made = _reads(func, args, kwargs), func.overloadpacket is aten.lift_fresh
        launches = self.launches and _launches(func)
        stack = traceback.extract_stack()[:-1] if reads or made or launches else None  # once: it is slow
        if reads:
            inside = any(frame.name in CAPTURED for frame in stack)
            (self.in_captured if inside else self.counts)[(func.overloadpacket.__name__, _place(stack))] += 1
        elif made:
            self.made[_place(stack)] += 1
        if launches:
            if _in_graph(stack):
                self.launched_in_graphs += 1
            else:  # who asked: tensordict's own lines would name every tensordict operation alike
                self.launched[_place(stack, ("flock_torchrl/", "torchrl/"))] += 1
        return func(*args, **kwargs)

    def __enter__(self) -> "HostReads":
        # The explicit waits are Python calls, not operators: counted by wrapping them while active.
        def counted(owner: Any, name: str) -> None:
            real = getattr(owner, name)

            def wait(*args: Any, **kwargs: Any) -> Any:
                self.counts[("synchronize", _place(traceback.extract_stack()[:-1]))] += 1
                return real(*args, **kwargs)

            setattr(owner, name, wait)
            self._restore.append((owner, name, real))

        self._restore: list[tuple[Any, str, Any]] = []
        counted(torch.cuda, "synchronize")
        counted(torch.cuda.Event, "synchronize")
        return super().__enter__()

    def __exit__(self, *exc: Any) -> Any:
        for owner, name, real in reversed(self._restore):
            setattr(owner, name, real)
        return super().__exit__(*exc)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def table(self, per: int = 1) -> str:
        """The counts (divided by ``per``, e.g. the iterations counted) by place, most first; the
        reads inside captured functions after them, marked."""
        lines = [f"{count / per:8.3f}  {op:<20} {place}" for (op, place), count in self.counts.most_common()]
        lines += [f"{count / per:8.3f}  {op:<20} {place} (captured)"
                  for (op, place), count in self.in_captured.most_common()]
        return "\n".join(lines) or "no host reads"
