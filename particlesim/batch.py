"""Batches of rollouts: ``vmap`` over parameter sets and initial states, split across devices.

Everything in particlesim is a pure function of arrays, so a batch is ``jax.vmap`` of the single case: a batch of
models is the same pytree with a leading axis on its array leaves (:func:`stack`, or
``model.with_params(inertia=batched)``), and a batch of states is a ``(B, n)`` array.

:func:`sharded_vmap` runs such a batch on several devices. The batch axis is split over a one-dimensional
device mesh (:func:`batch_mesh`) with :func:`jax.shard_map`: every device runs the vmapped function on its own
slice, so an adaptive solver's loop on one device stops when *its* slice is done (no cross-device
synchronisation per step) and each batch member sees exactly the operations it sees unsharded. The same code runs

* on one CPU (a mesh of one device: plain ``vmap``);
* on the CPU split into ``k`` host devices (``XLA_FLAGS=--xla_force_host_platform_device_count=k``, set before
  JAX starts), which is how the tests exercise it;
* on several GPUs of one machine: :func:`batch_mesh` takes ``jax.devices()``;
* on several machines: call ``jax.distributed.initialize()`` first in every process; ``jax.devices()`` then lists
  the devices of all processes, :func:`batch_mesh` spans them, and each process feeds its part of the batch
  (``jax.make_array_from_process_local_data(NamedSharding(mesh, P("batch")), local_part)``) — see the README.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec as P

from . import _xla
from ._ode import _concrete
from ._threads import run_parts, splits_safely, threads_apply, usable_cores

__all__ = ["AXIS", "batch_mesh", "stack", "param_axes", "sharded_vmap"]

#: Name of the batch axis of the device mesh.
AXIS = "batch"


def batch_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A one-dimensional mesh over ``devices`` (default: all of ``jax.devices()``) with the axis :data:`AXIS`."""
    devs = list(jax.devices() if devices is None else devices)
    if not devs:
        raise ValueError("batch_mesh: no devices given")
    return Mesh(np.asarray(devs, dtype=object), (AXIS,))


def stack(items: Sequence[Any]) -> Any:
    """Stack equal-structure pytrees (e.g. models that differ only in parameter values) along a new leading axis."""
    items = list(items)
    if not items:
        raise ValueError("stack: nothing to stack")
    structs = {jax.tree.structure(x) for x in items}
    if len(structs) != 1:
        raise ValueError("stack: the items differ in structure (static fields, joint layout or None leaves); "
                         "only parameter values may differ within a batch")
    return jax.tree.map(lambda *xs: jnp.stack(xs), *items)


def param_axes(model: Any, *names: str) -> Any:
    """``in_axes`` for a model batched only in the parameter fields ``names`` (e.g. ``"inertia"``): those are 0,
    every other leaf ``None`` (shared by the whole batch). For ``jax.vmap`` and :func:`sharded_vmap`."""
    axes = jax.tree.map(lambda _: None, model)
    for n in names:
        if getattr(model, n, None) is None:
            raise ValueError(f"param_axes: the model has no array field {n!r}")
    return eqx.tree_at(lambda m: [getattr(m, n) for n in names], axes, [0] * len(names),
                       is_leaf=lambda x: x is None)


def _is_none(x) -> bool:
    return x is None


def _leaf_axes(in_axes, args) -> list[int | None]:
    """``in_axes`` (a vmap-style prefix per argument) broadcast to one entry (0 or None) per leaf of ``args``,
    in the order of ``jax.tree.leaves(args)``."""
    prefix = tuple(in_axes) if isinstance(in_axes, (tuple, list)) else (in_axes,) * len(args)
    if len(prefix) != len(args):
        raise ValueError(f"in_axes has {len(prefix)} entries for {len(args)} arguments")
    out = []
    for i, (ax, a) in enumerate(zip(prefix, args)):
        ax_leaves, ax_def = jax.tree.flatten(ax, is_leaf=_is_none)
        try:
            subtrees = ax_def.flatten_up_to(a)
        except (ValueError, TypeError) as e:
            raise ValueError(f"in_axes of argument {i} does not match its structure: {e}") from None
        for leaf_ax, sub in zip(ax_leaves, subtrees):
            if leaf_ax not in (0, None):
                raise ValueError(f"in_axes entries must be 0 (batched along the leading axis) or None, got "
                                 f"{leaf_ax!r}")
            out += [leaf_ax] * len(jax.tree.leaves(sub))
    return out


def _batch_size(leaves, axes) -> int:
    sizes = set()
    for leaf, ax in zip(leaves, axes):
        if ax == 0:
            if jnp.ndim(leaf) == 0:
                raise ValueError("a batched argument needs a leading batch axis, got a scalar")
            sizes.add(int(jnp.shape(leaf)[0]))
    if len(sizes) != 1:
        raise ValueError(f"batched arguments disagree on the batch size: {sorted(sizes)} "
                         "(or no batched array was given)")
    return sizes.pop()


def sharded_vmap(fn: Callable, in_axes: int | None | Sequence[Any] = 0, *, mesh: Mesh | None = None,
                 chunk: int | None = None, threads: int | None = None) -> Callable:
    """``jax.jit(jax.vmap(fn, in_axes))`` with the batch split across the devices of ``mesh``.

    Args:
        fn: a function of single (unbatched) arguments returning a pytree of arrays.
        in_axes: as for ``jax.vmap`` but with entries 0 (batched along the leading axis) or ``None`` (the same
            for all members, replicated on every device), per argument or as a pytree prefix of it
            (:func:`param_axes` builds one for a model batched in some parameter fields).
        mesh: a one-dimensional mesh with axis :data:`AXIS` (default :func:`batch_mesh` over all devices).
        chunk: ``None`` vectorises each device's whole slice (``vmap``). An integer runs the slice as a loop
            over chunks of that many members (``jax.lax.map(..., batch_size=chunk)``; ``chunk=1`` a plain
            ``jax.lax.map``, one member per iteration). Prefer a small chunk (4-8) for adaptive rollouts on CPU:
            vectorised members step together until the slowest is done and every step carries the whole slice;
            on the 18-joint Krang a chunk of 4 ran 2.4x faster per member than a vectorised batch of 64
            (``benchmarks/batched_rollouts.py``). Particle mechanisms run fastest one member at a time
            (``chunk=1``): on 1024 quarter cars 1.2x the throughput of chunks of 8 and 2.5x that of vmap with
            Tsit5, 1.0x and 1.8x with Bosh3 (``benchmarks/mechanism_engine.py``).
        threads: on a mesh of one device, a batch passed from Python (concrete arrays, outside any trace) is split
            into this many equal parts, each run by the same compiled program on its own thread, so that every
            core works (XLA:CPU runs a rollout's loop on one core). ``None`` (default): the cores this process may
            run on (its CPU affinity, at most its control group's CPU quota); 1: one program. Parts are whole
            multiples of ``chunk`` members (the last part padded with copies of the last member, dropped from the
            result), so with a ``chunk`` dividing the batch every member sees the operations it sees in one
            program (a short last chunk is vectorised with the padding instead of alone: equal to round-off); with
            ``vmap`` (no chunk) the members of a part step together, as on one device of a mesh. Several devices
            (host devices or GPUs) split the batch over the mesh instead.

    Returns:
        A function of the batched arguments whose outputs carry the batch on their leading axis, split across the
        mesh (jitted: inside a caller's trace it is traced inline). The batch size must be a multiple of the
        number of devices (pad it otherwise).
    """
    mesh = batch_mesh() if mesh is None else mesh
    if mesh.axis_names != (AXIS,):
        raise ValueError(f"sharded_vmap needs a one-dimensional mesh with axis {AXIS!r}, got {mesh.axis_names}")
    if chunk is not None and (not isinstance(chunk, (int, np.integer)) or chunk < 1):
        raise ValueError(f"chunk must be a positive integer or None, got {chunk!r}")
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer))
                                or threads < 1):
        raise ValueError(f"threads must be a positive integer or None, got {threads!r}")
    ndev = mesh.devices.size

    @_xla.TopJit
    def run(*args):
        leaves, treedef = jax.tree.flatten(args)
        axes = _leaf_axes(in_axes, args)
        b = _batch_size(leaves, axes)
        if b % ndev:
            raise ValueError(f"a batch of {b} does not split evenly over {ndev} devices; pad it to a multiple "
                             f"of {ndev}")
        batched = [i for i, ax in enumerate(axes) if ax == 0]

        def per_device(*local):
            flat = jax.tree.leaves(local)

            def member(xs):
                full = list(flat)
                for i, x in zip(batched, xs):
                    full[i] = x
                return fn(*jax.tree.unflatten(treedef, full))

            xs = [flat[i] for i in batched]
            if chunk is None:
                return jax.vmap(member)(xs)
            if chunk == 1:  # a plain loop: lax.map's batch_size would vmap every member over an axis of one
                return jax.lax.map(member, xs)
            return jax.lax.map(member, xs, batch_size=int(chunk))

        specs = jax.tree.unflatten(treedef, [P(AXIS) if ax == 0 else P() for ax in axes])
        # check_vma=False: diffrax's loops carry values that are per-device by construction.
        return jax.shard_map(per_device, mesh=mesh, in_specs=tuple(specs), out_specs=P(AXIS),
                             check_vma=False)(*args)

    name = getattr(fn, "__name__", type(fn).__name__)

    def call(*args):
        parts = 1
        if ndev == 1 and _xla.top_level() and threads_apply(mesh.devices.flat[0].platform):
            parts = usable_cores() if threads is None else int(threads)
        if parts > 1:
            leaves, treedef = jax.tree.flatten(args)
            if all(map(_concrete, leaves)):  # no tracer among them (one leaked from a trace stays one program)
                axes = _leaf_axes(in_axes, args)
                b = _batch_size(leaves, axes)
                if b == 0:
                    return run(*args)
                unit = 1 if chunk is None else int(chunk)
                per = -(-b // (parts * unit)) * unit  # members per part, a whole number of chunks
                parts = -(-b // per)
                if parts > 1:
                    return _in_parts(run, leaves, treedef, axes, b, per, parts, name)
        return run(*args)

    call.jit = run  # the compiled program (of one part, or of the whole batch)
    # one program over the whole batch (no threads): lower with the top-level compiler options (TopJit.lower),
    # trace and eval_shape as the plain jit's (as TopJit forwards them)
    call.lower, call.trace, call.eval_shape = run.lower, run.trace, run.eval_shape
    functools.update_wrapper(call, fn, assigned=("__doc__",), updated=())
    return call


def _in_parts(run, leaves, treedef, axes, b: int, per: int, parts: int, name: str):
    """``run`` on ``parts`` parts of ``per`` members, each on its own thread (:func:`particlesim._threads.run_parts`);
    the batch padded to ``parts * per`` members with copies of its last one, cut off after. A part program with a
    LAPACK call spreading a batch over XLA's intra-op pool (:func:`particlesim._threads.splits_safely`: e.g. a
    factorisation per member under ``vmap``) cannot run beside its copies: the batch then runs as one program."""
    pad = parts * per - b
    chunks = [[] for _ in range(parts)]
    for leaf, ax in zip(leaves, axes):
        if ax == 0:
            x = jnp.asarray(leaf)
            if pad:
                x = jnp.concatenate([x, jnp.broadcast_to(x[-1:], (pad,) + x.shape[1:])])
            for k in range(parts):
                chunks[k].append(x[k * per:(k + 1) * per])
        else:
            for k in range(parts):
                chunks[k].append(leaf)
    args = [jax.tree.unflatten(treedef, c) for c in chunks]
    key = (treedef, tuple((jnp.shape(x), jnp.result_type(x), ax) for x, ax in zip(chunks[0], axes)))
    if not splits_safely(run, args[0], key):
        return run(*jax.tree.unflatten(treedef, leaves))
    outs = run_parts(run, args, what=f"sharded_vmap({name}) over a batch of {b} in {parts} parts",
                     describe=lambda k: f"part {k + 1} (members {k * per}..{min(b, (k + 1) * per) - 1})")
    return _join(outs, b)


@functools.partial(jax.jit, static_argnames="size")
def _join(outs, size: int):
    """The parts' outputs (pytrees with the batch leading) as one batch of ``size`` members."""
    return jax.tree.map(lambda *xs: jnp.concatenate(xs)[:size], *outs)
