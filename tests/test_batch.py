"""Batched rollouts and their split across devices (particlesim.batch).

The 8-device case runs in a subprocess: the number of CPU host devices is fixed when JAX starts
(``XLA_FLAGS=--xla_force_host_platform_device_count=8``), and this test process has already started with one.

Sharded against unsharded: the batch split over 8 devices (2 members each) equals, bit for bit, the same batch
on one device looped in chunks of 2 (``chunk=2``): each member sees the same operations whichever device runs its
slice. (XLA compiles the two per-slice programs alike today; it does not promise to, so a failure after an XLA
upgrade could be that rather than the split.) Against the whole batch vectorised at once (a batch of 16 in one
program, under the caller's jit with XLA's default options) the step counts agree exactly and the states to
WHOLE_BATCH_RTOL. That bound was 1e-12 until the link poses were composed by pointer jumping, which moved this
seed's velocities from 4.7e-13 to 1.1e-12 relative (its other seeds: at most 3.2e-13 against 4.7e-13). The
difference is batching round-off carried along 0.2 s of falling arms: a vectorised batch of 16 rounds differently
from one of 2, and with both compiled with the same options the link-by-link poses give 1.1e-12 on this seed too
(six seeds 8e-14 to 1.1e-12). The split itself is what the bitwise check tests; the bound now guards against a
member's rollout changing, at 1e-10, about 100 times the round-off seen and far below any modelling error.
"""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.batch import batch_mesh, param_axes, sharded_vmap, stack
from particlesim.simulate import simulate
from particlesim.tree import forward_dynamics
from particlesim.io import load_urdf

WHOLE_BATCH_RTOL = 1e-10  # whole vectorised batch vs sharded, relative to the batch's largest |value| (see above)
LOOP_RTOL = 1e-12  # a member of the batch vs the same rollout alone (measured 2e-13)
GRAVITY = (0.0, -9.81, 0.0)
URDF = "krang/urdf/krang_fixed_wheel_2018-04.urdf"

SCRIPT = textwrap.dedent("""
    import json, os, sys
    import jax, jax.numpy as jnp, numpy as np
    import particlesim
    from particlesim.batch import batch_mesh, param_axes, sharded_vmap
    from particlesim.data import data_dir
    from particlesim.simulate import simulate
    from particlesim.io import load_urdf
    from particlesim.tree import forward_dynamics

    model = load_urdf(data_dir() / "%s", gravity=(0.0, -9.81, 0.0))
    B = 16
    rng = np.random.default_rng(0)
    models = model.with_params(inertia=model.inertia[None] * rng.uniform(0.8, 1.2, (B, model.nq, 1)))
    q0 = jnp.asarray(rng.uniform(-0.5, 0.5, (B, model.nq)))
    qd0 = jnp.zeros((B, model.nq))
    axes = (param_axes(model, "inertia"), 0, 0)

    def rollout(m, q0, qd0):
        s = simulate(forward_dynamics, m, q0, qd0, 0.0, 0.2, solver="tsit5", rtol=1e-8, atol=1e-10)
        return s.q[-1], s.qd[-1], s.steps

    plain = jax.jit(jax.vmap(rollout, in_axes=axes))(models, q0, qd0)
    sharded = sharded_vmap(rollout, axes)(models, q0, qd0)
    looped = sharded_vmap(rollout, axes, mesh=batch_mesh(jax.devices()[:1]), chunk=B // 8)(models, q0, qd0)
    try:
        sharded_vmap(rollout, axes)(models.with_params(inertia=models.inertia[:12]),
                                    q0[:12], qd0[:12])
        uneven = "no error"
    except ValueError as e:
        uneven = str(e)
    out = {"devices": len(jax.devices()),
           "shard_devices": len(sharded[0].sharding.device_set),
           "looped_devices": len(looped[0].sharding.device_set),
           "bitwise_looped": [bool(np.array_equal(np.asarray(a), np.asarray(b))) for a, b in zip(looped, sharded)],
           "q_diff": float(np.max(np.abs(np.asarray(plain[0]) - np.asarray(sharded[0])))),
           "qd_diff": float(np.max(np.abs(np.asarray(plain[1]) - np.asarray(sharded[1])))),
           "q_scale": float(np.max(np.abs(np.asarray(plain[0])))),
           "qd_scale": float(np.max(np.abs(np.asarray(plain[1])))),
           "steps_plain": np.asarray(plain[2]).tolist(), "steps_sharded": np.asarray(sharded[2]).tolist(),
           "uneven": uneven}
    print("RESULT" + json.dumps(out))
""") % URDF


@pytest.fixture(scope="module")
def krang(shared_data):
    return load_urdf(shared_data / URDF, gravity=GRAVITY)


def _rollout(m, q0, qd0):
    s = simulate(forward_dynamics, m, q0, qd0, 0.0, 0.1, solver="tsit5", rtol=1e-8, atol=1e-10)
    return s.q[-1], s.qd[-1]


def test_sharded_batch_on_eight_host_devices_equals_unsharded():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=8", JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = next(x for x in proc.stdout.splitlines() if x.startswith("RESULT"))
    r = json.loads(line[len("RESULT"):])
    print(r)
    assert r["devices"] == 8 and r["shard_devices"] == 8  # the batch really was split over 8 devices
    assert r["looped_devices"] == 1
    assert r["bitwise_looped"] == [True, True, True]  # q, qd and step counts: the split changes no operation
    assert r["steps_plain"] == r["steps_sharded"]  # vectorised whole: every member took exactly the same steps
    assert r["q_diff"] <= WHOLE_BATCH_RTOL * r["q_scale"]
    assert r["qd_diff"] <= WHOLE_BATCH_RTOL * r["qd_scale"]
    assert "does not split evenly over 8 devices" in r["uneven"]


@pytest.mark.parametrize("chunk", [None, 2, 1])
def test_batch_of_parameter_sets_equals_single_rollouts(krang, chunk):
    """One device, whole batch vectorised (chunk None), looped in chunks of 2 (the last one short) or one member
    after another (chunk 1, a plain loop without vmap): every member equals its own rollout."""
    rng = np.random.default_rng(3)
    b = 3
    inertias = krang.inertia[None] * jnp.asarray(rng.uniform(0.8, 1.2, (b, krang.nq, 1)))
    q0 = jnp.asarray(rng.uniform(-0.5, 0.5, (b, krang.nq)))
    qd0 = jnp.asarray(rng.normal(0.0, 0.3, (b, krang.nq)))
    axes = (param_axes(krang, "inertia"), 0, 0)
    q, qd = sharded_vmap(_rollout, axes, mesh=batch_mesh(jax.devices()[:1]), chunk=chunk)(
        krang.with_params(inertia=inertias), q0, qd0)
    single = jax.jit(_rollout)
    for i in range(b):
        qi, qdi = single(krang.with_params(inertia=inertias[i]), q0[i], qd0[i])
        assert np.max(np.abs(np.asarray(q[i]) - np.asarray(qi))) <= LOOP_RTOL * np.max(np.abs(np.asarray(qi)))
        assert np.max(np.abs(np.asarray(qd[i]) - np.asarray(qdi))) <= LOOP_RTOL * np.max(np.abs(np.asarray(qdi)))


def test_batches_split_over_threads_on_one_device(krang, monkeypatch):
    """On a one-device mesh a batch passed from Python runs in parts, one per thread, each a whole number of chunks
    (6 Krang members, chunks of 2, 2 threads: parts of 4 members, the last padded with 2 copies of the last member):
    bit for bit the result of one program, members and step counts (the batch a multiple of the chunk: a short last
    chunk would be vectorised with the padding instead of alone); a replicated argument goes to every part; inside a
    caller's ``jit`` the batch is one program; ``threads`` must be a positive integer."""
    from particlesim import batch as batch_module

    rng = np.random.default_rng(8)
    b = 6
    inertias = krang.inertia[None] * jnp.asarray(rng.uniform(0.8, 1.2, (b, krang.nq, 1)))
    models = krang.with_params(inertia=inertias)
    q0 = jnp.asarray(rng.uniform(-0.5, 0.5, (b, krang.nq)))
    qd0 = jnp.asarray(rng.normal(0.0, 0.3, (krang.nq,)))

    def rollout(model, q0, qd0):
        sol = simulate(forward_dynamics, model, q0, qd0, 0.0, 0.1, solver="tsit5", rtol=1e-8, atol=1e-10)
        return sol.q[-1], sol.steps

    axes = (param_axes(krang, "inertia"), 0, None)
    mesh = batch_mesh(jax.devices()[:1])
    parted = []
    real = batch_module._in_parts

    def spy(run, leaves, treedef, ax, size, per, parts, name):
        parted.append((size, per, parts))
        return real(run, leaves, treedef, ax, size, per, parts, name)

    monkeypatch.setattr(batch_module, "_in_parts", spy)
    one = sharded_vmap(rollout, axes, mesh=mesh, chunk=2, threads=1)(models, q0, qd0)
    assert parted == []
    two = sharded_vmap(rollout, axes, mesh=mesh, chunk=2, threads=2)(models, q0, qd0)
    assert parted == [(6, 4, 2)]
    for x, y in zip(one, two):
        assert x.shape[0] == b
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    parted.clear()
    inside = jax.jit(sharded_vmap(rollout, axes, mesh=mesh, chunk=2, threads=2))(models, q0, qd0)
    assert parted == []
    np.testing.assert_array_equal(np.asarray(inside[1]), np.asarray(one[1]))
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="threads must be a positive integer"):
            sharded_vmap(rollout, axes, threads=bad)
    assert sharded_vmap(lambda a: 2.0 * a, mesh=mesh, threads=2)(jnp.zeros((0, 3))).shape == (0, 3)  # empty batch


def test_stack_builds_a_batch_of_models(krang):
    ms = stack([krang, krang.with_params(inertia=krang.inertia * 1.1)])
    assert ms.inertia.shape == (2, krang.nq, 10)
    np.testing.assert_array_equal(np.asarray(ms.inertia[1]), np.asarray(krang.inertia * 1.1))
    with pytest.raises(ValueError, match="differ in structure"):
        stack([krang, krang.with_params(viscous=jnp.ones(krang.nq))])


def test_bad_batches_are_refused(krang):
    f = sharded_vmap(lambda a, b: a + b)
    with pytest.raises(ValueError, match="disagree on the batch size"):
        f(jnp.ones((3, 2)), jnp.ones((4, 2)))
    with pytest.raises(ValueError, match="must be 0"):
        sharded_vmap(lambda a: a, in_axes=1)(jnp.ones((3, 2)))
    with pytest.raises(ValueError, match="leading batch axis"):
        f(jnp.ones(()), jnp.ones(()))
    with pytest.raises(ValueError, match="chunk must be a positive integer"):
        sharded_vmap(lambda a: a, chunk=0)
    with pytest.raises(ValueError, match="does not match its structure"):
        sharded_vmap(lambda m: m.inertia, in_axes=(param_axes(krang, "inertia"),))(jnp.ones(3))
    with pytest.raises(ValueError, match="no array field 'payload'"):
        param_axes(krang, "payload")
