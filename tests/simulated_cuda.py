"""A CUDA device simulated on the CPU, so the GPU path's device discipline is tested without a GPU.

Inside :func:`simulated_cuda` a tensor asked for on ``cuda`` (``device="cuda"``, ``.to("cuda")``,
``.cuda()``, a module's ``.to``) is a CPU tensor of the class :class:`OnGpu`, which says it lives
on ``cuda:0`` and, as a tensor there would, refuses to meet a CPU tensor of one or more dimensions
in an operation (a CPU scalar, a CPU index or a copy across is fine, as on CUDA). A random draw
for the device with a CPU generator is refused too, and so is a CPU tensor given to a CUDA graph
(``CudaGraphModule``), whose replays would never see its new values. So code that makes a tensor
on the CPU and uses it with the device's raises here the error it would raise on a GPU, and code
that runs here to the end keeps every tensor of its step where the device's tensors are.

What it does not simulate: CUDA graphs (``CudaGraphModule`` calls its function as it is, as
without CUDA), pinned memory (``pin_memory()`` is the tensor itself), streams, the CUDA
generator's own sequence (``torch.Generator(device="cuda")`` draws as a CPU one), memory figures
(zero) and ``torch.compile`` (dynamo cannot trace these tensors: a compiled function runs
eagerly). Those need a GPU: ``tests/test_cuda.py``.

The tensors keep their values, so a run's results are the CPU run's (bitwise, where nothing above
differs). :func:`start` turns it on for a whole process (``sitecustomize.py`` next to this file,
for the benchmarks' child processes).
"""

from __future__ import annotations

import contextlib
import time
from typing import Any, Callable
from unittest import mock

import torch
from tensordict import is_tensor_collection
from torch.overrides import TorchFunctionMode
from torch.utils._pytree import tree_flatten, tree_map

CUDA = torch.device("cuda", 0)
_CPU = torch.device("cpu")


class OnGpu(torch.Tensor):
    """A CPU tensor that says it lives on ``cuda:0`` and refuses CPU tensors as one there would."""

    @property
    def device(self) -> torch.device:
        return CUDA

    @property
    def is_cuda(self) -> bool:
        return True

    @property
    def is_cpu(self) -> bool:
        return False

    def get_device(self) -> int:
        return 0

    def __reduce_ex__(self, protocol):  # saved as a plain tensor: read back as map_location="cpu" would
        with torch._C.DisableTorchFunctionSubclass():
            return self.as_subclass(torch.Tensor).__reduce_ex__(protocol)

    def __deepcopy__(self, memo):
        if id(self) not in memo:
            with torch._C.DisableTorchFunctionSubclass():
                data = self.as_subclass(torch.Tensor).detach().clone()
                memo[id(self)] = torch.Tensor._make_subclass(type(self), data, self.requires_grad)
        return memo[id(self)]

    def __repr__(self, *, tensor_contents=None) -> str:
        with torch._C.DisableTorchFunctionSubclass():
            return f"OnGpu({self.as_subclass(torch.Tensor)!r})"

    @classmethod
    def __torch_function__(cls, func, types, args=(), kwargs=None):
        return _call(func, args, kwargs or {})


class OnGpuParameter(OnGpu, torch.nn.Parameter):
    """A module's parameter on the simulated device."""


def _names_cuda(d: Any) -> bool:
    return (isinstance(d, torch.device) and d.type == "cuda") or (isinstance(d, str) and d.split(":")[0] == "cuda")


def _names_cpu(d: Any) -> bool:
    return (isinstance(d, torch.device) and d.type == "cpu") or (isinstance(d, str) and d.split(":")[0] == "cpu")


def _to_cpu_name(d: Any) -> Any:
    return _CPU if _names_cuda(d) else d


def _target(func: Callable, args: tuple, kwargs: dict) -> str | None:
    """Where a call puts its result: ``"cuda"``, ``"cpu"``, or ``None`` (where its inputs are)."""
    if func is torch.Tensor.cuda:
        return "cuda"
    if func is torch.Tensor.cpu:
        return "cpu"
    wanted = [kwargs.get("device")]
    if func is torch.Tensor.to:
        wanted = [*args[1:], kwargs.get("device"), kwargs.get("other")]
    for d in wanted:
        if isinstance(d, torch.Tensor):
            return "cuda" if isinstance(d, OnGpu) else "cpu"
        if _names_cuda(d):
            return "cuda"
        if _names_cpu(d):
            return "cpu"
    return None


# Calls that may take tensors of both places: moves and copies, and the checks modules make.
_ACROSS = {torch.Tensor.to, torch.Tensor.cuda, torch.Tensor.cpu, torch.Tensor.copy_, torch.Tensor.new_tensor,
           torch._has_compatible_shallow_copy_type, torch.Tensor.data.__set__, torch.Tensor.grad.__set__}
# CUDA takes the index (and the values) of an indexing from the CPU.
_INDEXING = {torch.Tensor.__getitem__, torch.Tensor.__setitem__}
# Calls whose result is not a tensor of the device (a Python value, a NumPy array).
_TO_HOST = {torch.Tensor.numpy, torch.Tensor.tolist, torch.Tensor.item}


def _refuse(func: Callable, what: str) -> None:
    name = getattr(func, "__qualname__", getattr(func, "__name__", repr(func)))
    raise RuntimeError(f"{what} (simulated CUDA, in {name})")


def _call(func: Callable, args: tuple, kwargs: dict) -> Any:
    tensors = [a for a in tree_flatten((args, kwargs))[0] if isinstance(a, torch.Tensor)]
    on_gpu = any(isinstance(a, OnGpu) for a in tensors)
    target = _target(func, args, kwargs)
    on_device = target == "cuda" or (target is None and on_gpu)  # where the result goes
    checked = [args[0]] if func in _INDEXING else tensors
    # Inside torch.vmap the tensors are functorch's wrappers, whose class says nothing: not checked.
    inside_vmap = any(torch._C._functorch.is_functorch_wrapped_tensor(a) for a in checked)
    if on_gpu and func not in _ACROSS and not inside_vmap:
        if any(not isinstance(a, OnGpu) and a.dim() > 0 for a in checked):
            _refuse(func, "Expected all tensors to be on the same device, but found at least two devices, "
                          "cuda:0 and cpu!")
    if func is torch.Tensor.numpy and isinstance(args[0], OnGpu):
        _refuse(func, "can't convert cuda:0 device type tensor to numpy. Use Tensor.cpu() to copy the tensor "
                      "to host memory first.")
    generator = kwargs.get("generator")
    if isinstance(generator, torch._C.Generator):
        if on_device != isinstance(generator, _Generator):
            _refuse(func, f"Expected a '{'cuda' if on_device else 'cpu'}' device type for generator")
    if func is torch.Tensor.pin_memory:
        return args[0]
    if func is torch.Tensor.is_pinned:
        return False
    if func is torch.Tensor.cuda:
        if isinstance(args[0], OnGpu):
            return args[0]
        func, args, kwargs = torch.Tensor.clone, args[:1], {}
    args, kwargs = tree_map(_to_cpu_name, args), tree_map(_to_cpu_name, kwargs)
    with torch._C.DisableTorchFunctionSubclass():
        out = func(*args, **kwargs)
        if func in (torch.Tensor.to, torch.Tensor.cpu) and out is args[0] and on_device != on_gpu:
            out = out.clone()  # a move across devices copies (the data here stays where it was)
    if func in _TO_HOST:
        return out
    if func is torch.Tensor.copy_:  # into its destination, which stays where it is
        return args[0]
    if func is torch.Tensor.to and out is args[0]:  # already there
        return args[0]
    if on_device:
        return tree_map(lambda o: o.as_subclass(OnGpu) if isinstance(o, torch.Tensor) and not isinstance(o, OnGpu)
                        else o, out)
    return tree_map(lambda o: o.as_subclass(torch.Tensor) if isinstance(o, OnGpu) else o, out)


class _Factories(TorchFunctionMode):
    """Calls on plain tensors and factories that ask for ``cuda``: made on the CPU as :class:`OnGpu`."""

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if any(issubclass(t, OnGpu) for t in types):
            return OnGpu.__torch_function__(func, types, args, kwargs)
        if (_target(func, args, kwargs) == "cuda" or isinstance(kwargs.get("generator"), torch._C.Generator)
                or func in (torch.Tensor.pin_memory, torch.Tensor.is_pinned)):
            return _call(func, args, kwargs)
        return func(*args, **kwargs)


class _Generator(torch._C.Generator):
    """``torch.Generator(device="cuda")``: a CPU generator that says it is the device's."""

    def __new__(cls, device: Any = "cpu"):
        if not _names_cuda(device):
            return torch._C.Generator(device=device)
        return torch._C.Generator.__new__(cls, device="cpu")

    @property
    def device(self) -> torch.device:
        return CUDA


def _parameter(new: Callable) -> Callable:
    def make(cls, data=None, requires_grad=True):
        if isinstance(data, OnGpu):
            with torch._C.DisableTorchFunctionSubclass():
                return torch.Tensor._make_subclass(OnGpuParameter, data, requires_grad)
        return new(cls, data, requires_grad)

    return make


def _back_on_device(out: Any) -> Any:
    def one(o: Any) -> Any:
        if is_tensor_collection(o):
            return o.apply(lambda t: t.as_subclass(OnGpu) if type(t) is torch.Tensor else t)
        return o.as_subclass(OnGpu) if type(o) is torch.Tensor else o

    return tree_map(one, out, is_leaf=is_tensor_collection)


def _holds_device_tensors(tree: Any) -> bool:
    for leaf in tree_flatten(tree, is_leaf=is_tensor_collection)[0]:
        tensors = leaf.values(True, True) if is_tensor_collection(leaf) else [leaf]
        if any(isinstance(t, OnGpu) for t in tensors):
            return True
    return False


def _vmap(real: Callable) -> Callable:
    """vmap's batched kernels give plain tensors: what a vmapped function of the device's tensors
    returns goes back on the device."""
    def vmap(func, *vargs, **vkwargs):
        inner = real(func, *vargs, **vkwargs)

        def run(*args, **kwargs):
            out = inner(*args, **kwargs)
            return _back_on_device(out) if _holds_device_tensors((args, kwargs)) else out

        return run

    return vmap


class _Event:
    """A CUDA event on the simulated device: ``record`` notes the host's clock (the CPU runs each
    operation as it is called, so the device's timeline is the host's)."""

    def __init__(self, enable_timing: bool = False, **kwargs: Any) -> None:
        self.time: float | None = None

    def record(self, stream: Any = None) -> None:
        self.time = time.perf_counter()

    def synchronize(self) -> None:
        pass

    def query(self) -> bool:
        return True

    def elapsed_time(self, end: "_Event") -> float:
        return 1000.0 * (end.time - self.time)


def _patches() -> list:
    from tensordict.nn import CudaGraphModule

    init = CudaGraphModule.__init__

    def without_graphs(self, *args, **kwargs):  # as without CUDA: it calls its function as it is
        with mock.patch("torch.cuda.is_available", lambda: False):
            init(self, *args, **kwargs)

    call = CudaGraphModule.__call__

    def given_the_devices_tensors(self, *args, **kwargs):  # a graph replays on its own copies of them
        leaves = []
        for leaf in tree_flatten((args, kwargs), is_leaf=is_tensor_collection)[0]:
            if is_tensor_collection(leaf):
                keys = getattr(self, "in_keys", None)
                leaf = leaf.select(*keys, strict=False) if keys else leaf
                leaves.extend(leaf.values(True, True))
            elif isinstance(leaf, torch.Tensor):
                leaves.append(leaf)
        device = getattr(self, "device", None)
        if (_names_cuda(device) or any(isinstance(t, OnGpu) for t in leaves)) and not all(
                isinstance(t, OnGpu) for t in leaves):
            _refuse(call, "a CUDA graph is given a CPU tensor: its replays would not see the tensor's new "
                          "values (CudaGraphModule)")
        return call(self, *args, **kwargs)

    cuda = {"Event": _Event, "is_available": lambda: True, "device_count": lambda: 1, "current_device": lambda: 0,
            "_lazy_init": lambda: None, "synchronize": lambda *a, **k: None,
            "is_current_stream_capturing": lambda: False, "get_device_name": lambda *a, **k: "simulated CUDA (CPU)",
            "max_memory_allocated": lambda *a, **k: 0, "memory_allocated": lambda *a, **k: 0,
            "reset_peak_memory_stats": lambda *a, **k: None, "empty_cache": lambda: None,
            "get_rng_state": lambda *a, **k: torch.get_rng_state(), "set_rng_state": lambda *a, **k: None,
            "manual_seed": lambda *a, **k: None, "manual_seed_all": lambda *a, **k: None}
    import torchrl.objectives.utils

    return [*(mock.patch(f"torch.cuda.{name}", value) for name, value in cuda.items()),
            mock.patch("torch.Generator", _Generator),
            mock.patch("torch.vmap", _vmap(torch.vmap)),
            mock.patch.object(torchrl.objectives.utils, "vmap", _vmap(torchrl.objectives.utils.vmap)),
            mock.patch("torch.compile", _eager_compile),
            mock.patch.object(torch.nn.Parameter, "__new__", _parameter(torch.nn.Parameter.__new__)),
            mock.patch.object(CudaGraphModule, "__init__", without_graphs),
            mock.patch.object(CudaGraphModule, "__call__", given_the_devices_tensors),
            # a module's .to("cuda") makes new parameters (of the device's class), as for a subclass
            mock.patch("torch.__future__._overwrite_module_params_on_conversion", True)]


def _eager_compile(model=None, **kwargs):
    """``torch.compile`` that returns its function: dynamo cannot trace the simulated tensors."""
    if model is None:
        return lambda fn: fn
    return model


@contextlib.contextmanager
def simulated_cuda():
    """Within: ``cuda`` is a CPU device that refuses the CPU's tensors (the module's docstring)."""
    with contextlib.ExitStack() as stack:
        for patch in _patches():
            stack.enter_context(patch)
        stack.enter_context(_Factories())
        try:
            yield
        finally:
            from flock_torchrl.world import geometry

            clear = getattr(geometry._constant, "cache_clear", None)  # (a test may have replaced it)
            if clear is not None:
                clear()  # the step's tables made for the simulated device


_STARTED: list = []


def start() -> None:
    """Simulate CUDA for the rest of this process (``sitecustomize.py``)."""
    if not _STARTED:
        _STARTED.append(simulated_cuda())  # held: a collected context manager would end it
        _STARTED[0].__enter__()
