"""Batched forward dynamics (articulated-body sweeps, batch innermost) and the O(N) one-state path of large trees,
against Pinocchio's ABA, our recursive Newton–Euler inverse dynamics, and per-state evaluation."""

import contextlib
import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from particlesim.errors import ModelError
from particlesim.tree import forward_dynamics, inverse_dynamics
from particlesim.io import load_urdf
from particlesim.tree.aba import UNROLL_LINKS, supports_aba
from tree_helpers import PinocchioOracle, max_rel, random_tree_urdf

#: Against Pinocchio's ABA (double precision, a different algorithm in a different frame convention).
PIN_RTOL = 1e-10
#: ``inverse_dynamics(forward_dynamics(tau)) == tau`` (Newton–Euler against the articulated-body sweeps).
ROUNDTRIP_RTOL = 1e-10
#: Batched against one state at a time (the same equations, different summation order).
SAME_RTOL = 1e-12
N_STATES = 32


@contextlib.contextmanager
def _sweeps_seen():
    """Records the batch width (lanes) of every call of the batched sweeps traced inside the block."""
    from particlesim.tree import aba as aba_module, dynamics

    widths = []

    def spy(model, q, qd, tau):
        widths.append(q.shape[1])
        return aba_module.aba(model, q, qd, tau)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dynamics, "aba", spy)
        yield widths


def _pin_aba(oracle, q, qd, tau):
    out = []
    for x, v, t in zip(q, qd, tau):
        qp, vp = oracle._qv(x, v)
        tp = np.zeros(oracle.model.nv)
        tp[oracle.idx] = t
        out.append(oracle.pin.aba(oracle.model, oracle.data, qp, vp, tp)[oracle.idx])
    return np.asarray(out)


@pytest.fixture(scope="module", params=["tree6", "tree40"])
def case(request):
    """A written-out tree and a looped one (Krang's batch is checked against ``abaInParallel`` on all 1024 states by
    ``benchmarks/krang_dynamics.py``; its one-state path by test_pinocchio.py)."""
    gravity = (0.0, 0.0, -9.81)
    urdf = random_tree_urdf(21, int(request.param[4:]), prismatic=0.3)
    model = load_urdf(urdf, gravity=gravity, limits="ignore")
    return model, PinocchioOracle(urdf, model.joint_names, gravity)


def test_batched_forward_dynamics_against_pinocchio(case):
    model, oracle = case
    assert supports_aba(model)
    rng = np.random.default_rng(5)
    q = rng.uniform(-2.0, 2.0, (N_STATES, model.nq))
    qd, tau = rng.normal(size=(2, N_STATES, model.nq))
    ours = np.asarray(jax.jit(forward_dynamics)(model, q, qd, tau))
    err = max_rel(ours, _pin_aba(oracle, q, qd, tau))
    print(f"{model.nq} joints ({'unrolled' if model.nq <= UNROLL_LINKS else 'loop'}): batched vs Pinocchio "
          f"{err:.2e}")
    assert err <= PIN_RTOL


def test_a_few_states_against_pinocchio(case):
    """A batch of at most one state per link (state by state, on the written-out tree) through the public function,
    with leading axes that broadcast, against Pinocchio's ABA."""
    from particlesim.tree.aba import state_by_state

    model, oracle = case
    n = model.nq
    if not state_by_state(1, n):
        pytest.skip("trees beyond UNROLL_LINKS keep their looped sweeps for any batch")
    rng = np.random.default_rng(17)
    k = n  # the most states the loop takes: one per link
    q, qd, tau = rng.uniform(-2.0, 2.0, (1, k, n)), rng.normal(size=n), rng.normal(size=(k, n))
    assert state_by_state(k, n) and not state_by_state(k + 1, n)  # the (1, k) batch below
    ours = np.asarray(forward_dynamics(model, q, qd, tau))
    assert ours.shape == (1, k, n)
    full = [np.broadcast_to(x, (1, k, n)).reshape(k, n) for x in (q, qd, tau)]
    assert max_rel(ours.reshape(k, n), _pin_aba(oracle, *full)) <= PIN_RTOL


def test_large_tree_batches_run_in_chunks_against_pinocchio(case):
    """Trees that loop over links evaluate a batch in chunks of at most LOOP_CHUNK_LINK_STATES / N states (here
    100 states of the 40-link tree: 2 chunks of 52, the last one padded)."""
    from particlesim.tree import aba as aba_module, dynamics

    model, oracle = case
    if model.n_joints <= UNROLL_LINKS:
        pytest.skip("written-out trees: test_large_batches_run_in_chunks_with_the_same_results")
    assert [aba_module.batch_chunks(s, n) for s, n in ((100, 40), (256, 200), (256, 33), (5, 5000))] == [2, 6, 3, 1]
    assert [aba_module.batch_lanes(p, n) for p, n in ((50, 40), (86, 100), (64, 40), (5, 40))] == [52, 88, 64, 5]
    rng = np.random.default_rng(15)
    q = rng.uniform(-2.0, 2.0, (100, model.n_joints))
    qd, tau = rng.normal(size=(2, 100, model.n_joints))
    assert max_rel(forward_dynamics(model, q, qd, tau), _pin_aba(oracle, q, qd, tau)) <= PIN_RTOL
    with _sweeps_seen() as widths:
        jax.make_jaxpr(lambda x: dynamics._batched.raw(model, x, x, x, None))(jnp.asarray(q))
    assert widths == [52]  # the public batch entry chunks: 2 chunks of 52 lanes


def test_large_tree_single_state_against_pinocchio(case):
    """Beyond UNROLL_LINKS a single state goes through the O(N) sweeps too."""
    model, oracle = case
    if model.nq <= UNROLL_LINKS:
        pytest.skip("small trees use the composite-inertia path for one state (tested in test_pinocchio.py)")
    rng = np.random.default_rng(6)
    q, qd, tau = rng.uniform(-2.0, 2.0, model.nq), rng.normal(size=model.nq), rng.normal(size=model.nq)
    ours = np.asarray(jax.jit(forward_dynamics)(model, q, qd, tau))
    assert max_rel(ours, _pin_aba(oracle, q[None], qd[None], tau[None])[0]) <= PIN_RTOL


@pytest.fixture(scope="module")
def loaded_tree(small_tree):
    """Friction, rotor inertia, joint springs and soft limits: every generalised force the sweeps take in."""
    n = small_tree.nq
    return small_tree.with_params(stiffness=jnp.linspace(1.0, 3.0, n), spring_ref=jnp.full(n, 0.2),
                                  limits=jnp.tile(jnp.array([-0.5, 0.5, 50.0, 2.0]), (n, 1)))


def test_batched_forces_round_trip_through_inverse_dynamics(loaded_tree):
    model = loaded_tree
    rng = np.random.default_rng(7)
    q = rng.uniform(-1.0, 1.0, (N_STATES, model.nq))
    qd, tau = rng.normal(size=(2, N_STATES, model.nq))
    fd = jax.jit(lambda q, qd, tau: forward_dynamics(model, q, qd, tau, smooth_friction=0.05))
    qdd = fd(q, qd, tau)
    back = jax.jit(jax.vmap(lambda q, qd, a: inverse_dynamics(model, q, qd, a, smooth_friction=0.05)))(q, qd, qdd)
    assert max_rel(back, tau) <= ROUNDTRIP_RTOL
    one = jax.jit(jax.vmap(lambda q, qd, t: forward_dynamics(model, q, qd, t, smooth_friction=0.05)))(q, qd, tau)
    assert max_rel(qdd, one) <= SAME_RTOL


def test_batch_axes_broadcast(small_tree):
    n = small_tree.nq
    rng = np.random.default_rng(8)
    q, qd, tau = rng.normal(size=(2, 3, n)), rng.normal(size=n), rng.normal(size=(3, n))
    out = jax.jit(forward_dynamics)(small_tree, q, qd, tau)
    assert out.shape == (2, 3, n)
    one = jax.jit(jax.vmap(forward_dynamics, in_axes=(None, 0, None, 0)))
    ref = np.stack([one(small_tree, q[i], qd, tau) for i in range(2)])
    assert max_rel(out, ref) <= SAME_RTOL


def test_models_outside_the_sweeps_batch_state_by_state():
    """Floating base (free joint): a batch is evaluated one state at a time, with the same results."""
    heavy_base = ('<link name="base"><inertial><mass value="2"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.2" '
                  'iyz="0" izz="0.15"/></inertial></link>')  # a floating base carries mass
    urdf = random_tree_urdf(4, 3).replace('<link name="base"/>', heavy_base)
    model = load_urdf(urdf, floating_base=True, limits="ignore")
    assert not supports_aba(model)
    rng = np.random.default_rng(9)
    q = np.concatenate([rng.normal(size=(3, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)),
                        rng.normal(size=(3, model.nq - 7))], axis=1)
    qd, tau = rng.normal(size=(2, 3, model.nv))
    out = jax.jit(forward_dynamics)(model, q, qd, tau)
    ref = jax.jit(jax.vmap(forward_dynamics, in_axes=(None, 0, 0, 0)))(model, q, qd, tau)
    assert max_rel(out, ref) <= SAME_RTOL


def test_batched_shapes_refused_by_name(small_tree):
    n = small_tree.nq
    with pytest.raises(ModelError, match=r"qd must have shape \(\.\.\., 5\)"):
        forward_dynamics(small_tree, np.zeros((2, n)), np.zeros((2, n + 1)), np.zeros((2, n)))
    with pytest.raises(ModelError, match="do not broadcast"):
        forward_dynamics(small_tree, np.zeros((2, n)), np.zeros((3, n)), np.zeros((2, n)))


@pytest.mark.parametrize("by_state", [False, True])  # the sweeps (any traced batch); a few states from Python
def test_batched_gradients(tiny_tree, by_state):
    from particlesim.tree import dynamics

    model = tiny_tree
    rng = np.random.default_rng(10)
    q, qd, tau = (jnp.asarray(rng.normal(size=(2, model.nq))) for _ in range(3))

    def f(q, qd, tau, inertia):
        m = eqx.tree_at(lambda m: m.inertia, model, inertia)
        if by_state:
            return dynamics._batched.raw(m, q, qd, tau, 0.1, True)
        return forward_dynamics(m, q, qd, tau, smooth_friction=0.1)

    check_grads(jax.jit(f), (q, qd, tau, model.inertia), order=1, modes=("fwd", "rev"))


def test_large_batches_run_in_chunks_with_the_same_results(small_tree):
    """A shallow tree's batch runs in chunks of about SHALLOW_CHUNK states (1509 states: 12 chunks of 126 lanes, the
    last one padded): the same values as state by state, leading batch axes kept. A deep tree's runs whole up to
    BATCH_CHUNK_ABOVE states and in chunks of about BATCH_CHUNK beyond: only the count differs (checked here), the
    chunked code is the same."""
    from particlesim.tree import aba as aba_module, dynamics

    lead = (3, aba_module.BATCH_CHUNK_ABOVE // 3 + 34)  # 1509 states
    size = lead[0] * lead[1]
    depth = aba_module.tree_depth(small_tree.parents)
    assert depth <= aba_module.SHALLOW_DEPTH
    assert aba_module.batch_chunks(size, small_tree.n_joints, depth) == 12 and size % 12
    assert aba_module.batch_chunks(size) == 2 and aba_module.batch_chunks(size, 5, aba_module.SHALLOW_DEPTH + 1) == 2
    n = small_tree.nq
    rng = np.random.default_rng(12)
    q, qd, tau = (rng.normal(size=lead + (n,)) for _ in range(3))
    out = forward_dynamics(small_tree, q, qd, tau)
    assert out.shape == lead + (n,)
    one = jax.jit(jax.vmap(jax.vmap(lambda a, b, c: forward_dynamics(small_tree, a, b, c))))
    assert max_rel(out, one(q, qd, tau)) <= SAME_RTOL
    with _sweeps_seen() as widths:
        jax.make_jaxpr(lambda x: dynamics._batched.raw(small_tree, x, x, x, None))(jnp.asarray(q))
    assert widths == [126]


def test_shallow_trees_chunk_by_depth():
    """Chunks of about SHALLOW_CHUNK states for trees at most SHALLOW_DEPTH deep (Krang's 1024 states: 8 chunks of 136
    lanes), the whole batch or chunks of about BATCH_CHUNK deeper; the depth counted from the parents; wide entries
    only for chunks of at least WIDE_BATCH states."""
    from particlesim.tree import aba as aba_module

    assert [aba_module.tree_depth(p) for p in ((), (-1,), (-1, -1), (-1, 0, 1), (-1, 0, 0, 2), (-1, 0, 1, 2, 2, 4))] \
        == [0, 1, 1, 3, 3, 5]
    shallow, deep = aba_module.SHALLOW_DEPTH, aba_module.SHALLOW_DEPTH + 1
    assert [aba_module.batch_chunks(s, 18, shallow) for s in (0, 5, 191, 192, 1024, 2048)] == [1, 1, 1, 2, 8, 16]
    assert aba_module.batch_lanes(-(-1024 // 8)) == 136
    assert [aba_module.batch_chunks(s, 18, deep) for s in (192, 1024, 1408, 2048)] == [1, 1, 1, 2]
    assert [aba_module.wide_batch(s, 18, shallow) for s in (705, 1024, 4096)] == [False, False, False]
    assert [aba_module.wide_batch(s, 18, deep) for s in (704, 705, 4096)] == [False, True, True]
    assert not aba_module.wide_batch(0, 18, deep)


def test_batches_padded_off_multiples_of_64_lanes(small_tree):
    """A batch of 64 states runs as 72 lanes (the last 8 copies of the last state): the same values as state by
    state."""
    from particlesim.tree.aba import batch_lanes

    assert [batch_lanes(p) for p in (0, 3, 40, 64, 512, 520, 768, 1024)] == [0, 3, 40, 72, 520, 520, 768, 1024]
    rng = np.random.default_rng(14)
    q, qd, tau = (rng.normal(size=(64, small_tree.nq)) for _ in range(3))
    out = forward_dynamics(small_tree, q, qd, tau)
    one = jax.jit(jax.vmap(lambda a, b, c: forward_dynamics(small_tree, a, b, c)))
    assert out.shape == q.shape and max_rel(out, one(q, qd, tau)) <= SAME_RTOL


def test_chunked_batches_differentiate(tiny_tree, monkeypatch):
    """The chunked layout (here 3 chunks of 8 for 22 states, the last one padded; chunk sizes made small) against
    state by state and finite differences, forward and reverse mode."""
    from particlesim.tree import aba as aba_module, dynamics

    monkeypatch.setattr(aba_module, "BATCH_CHUNK_ABOVE", 4)
    monkeypatch.setattr(aba_module, "BATCH_CHUNK", 8)
    monkeypatch.setattr(aba_module, "SHALLOW_CHUNK", 8)
    assert aba_module.batch_chunks(22) == 3
    assert aba_module.batch_chunks(22, tiny_tree.n_joints, aba_module.tree_depth(tiny_tree.parents)) == 3
    model = tiny_tree
    rng = np.random.default_rng(13)
    q, qd, tau = (jnp.asarray(rng.normal(size=(22, model.nq))) for _ in range(3))

    def f(q, qd, tau, inertia):
        m = eqx.tree_at(lambda m: m.inertia, model, inertia)
        return dynamics._batched.raw(m, q, qd, tau, 0.1)

    fn = jax.jit(f)
    ref = jax.jit(jax.vmap(lambda a, b, c: forward_dynamics(model, a, b, c, smooth_friction=0.1)))(q, qd, tau)
    assert max_rel(fn(q, qd, tau, model.inertia), ref) <= SAME_RTOL
    check_grads(fn, (q, qd, tau, model.inertia), order=1, modes=("fwd", "rev"))


def test_batches_evenly_divided_still_run_in_chunks(tiny_tree, monkeypatch):
    """The sweeps see chunks, not the whole batch, also when the batch divides evenly (16 states in 2 chunks of 8;
    chunk sizes made small), and an empty batch passes through."""
    from particlesim.tree import aba as aba_module, dynamics

    monkeypatch.setattr(aba_module, "BATCH_CHUNK_ABOVE", 4)
    monkeypatch.setattr(aba_module, "BATCH_CHUNK", 8)
    monkeypatch.setattr(aba_module, "SHALLOW_CHUNK", 8)
    x = jnp.zeros((16, tiny_tree.nq))
    with _sweeps_seen() as widths:
        jax.make_jaxpr(lambda x: dynamics._batched.raw(tiny_tree, x, x, x, None))(x)
    assert widths == [8]
    empty = np.zeros((0, tiny_tree.nq))
    assert forward_dynamics(tiny_tree, empty, empty, empty).shape == (0, tiny_tree.nq)


@pytest.mark.parametrize("states", [2, 8, 705])  # 5 links: state by state (from Python), the sweeps, a wide batch
def test_a_batch_compiles_once_per_structure(small_tree, states, monkeypatch):
    """New parameter values and new states of the same shape reuse the compiled batch (trace counter). The wide
    batch: the tree treated as deep (a shallow one's chunks are narrow)."""
    from particlesim import _ode
    from particlesim.tree import aba as aba_module

    monkeypatch.setattr(aba_module, "BATCH_THREADS", 1)  # one program (parts: test_batches_split_over_threads)
    if states >= aba_module.WIDE_BATCH:
        monkeypatch.setattr(aba_module, "SHALLOW_DEPTH", 0)
    wide = aba_module.wide_batch(states, small_tree.n_joints, aba_module.tree_depth(small_tree.parents))
    assert wide == (states >= aba_module.WIDE_BATCH)
    name = "forward_dynamics wide batch" if wide else "forward_dynamics batch"
    rng = np.random.default_rng(11)
    q, qd, tau = (rng.normal(size=(states, small_tree.nq)) for _ in range(3))
    forward_dynamics(small_tree, q, qd, tau)
    before = _ode.TRACES[name]
    assert before > 0
    heavier = small_tree.with_params(inertia=small_tree.inertia * 1.3, viscous=small_tree.viscous * 2.0)
    out = forward_dynamics(heavier, q + 0.1, qd, tau)
    forward_dynamics(small_tree, q - 0.2, qd * 3.0, tau)
    assert _ode.TRACES[name] == before
    ref = jax.vmap(lambda a, b, c: forward_dynamics(heavier, a, b, c))(q + 0.1, qd, tau)
    assert max_rel(out, ref) <= SAME_RTOL


def test_a_few_states_run_state_by_state(small_tree):
    """A batch of at most one state per link passed from Python (here 5 links: 1 and 4 states, leading axes
    kept) loops over the one-state program instead of running the written-out sweeps, whose hundreds of small kernels
    a few states do not repay; 6 states, and any batch inside a caller's trace (here ``jit`` and ``vmap``), take the
    sweeps, also when only the model is traced and the states are captured as concrete arrays (a ``vmap`` over
    parameter sets, ``jit``, ``grad``). The loop runs no sweeps (a spy), and both paths equal state-by-state calls,
    friction included."""
    from particlesim.tree import aba as aba_module, dynamics

    n = small_tree.n_joints
    assert [aba_module.state_by_state(s, n) for s in (0, 1, 2, 5, 6)] == [False, True, True, True, False]
    assert not aba_module.state_by_state(1, 40)  # trees beyond UNROLL_LINKS keep their looped sweeps
    rng = np.random.default_rng(16)
    one = jax.jit(jax.vmap(lambda a, b, c: forward_dynamics(small_tree, a, b, c, smooth_friction=0.1)))
    entry, chosen = dynamics._batched, []

    def recorded(*args):
        chosen.append(args[5])
        return entry(*args)

    # one state, the fewest that take the sweeps, and two leading axes on either side of the bound (each shape
    # compiles its own programs: the test's cost is per shape; the bound itself is asserted above)
    for lead in ((1,), (6,), (2, 2), (2, 3)):
        q, qd, tau = (rng.normal(size=lead + (n,)) for _ in range(3))
        chosen.clear()
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(dynamics, "_batched", recorded)
            out = forward_dynamics(small_tree, q, qd, tau, smooth_friction=0.1)  # from Python
            jax.jit(lambda a, b, c: forward_dynamics(small_tree, a, b, c, smooth_friction=0.1))(q, qd, tau)
            jax.vmap(lambda a: forward_dynamics(small_tree, a, qd, tau, smooth_friction=0.1))(q[None])
            states = tuple(jnp.asarray(x) for x in (q, qd, tau))  # concrete, captured; only the model traced
            scaled = lambda s: small_tree.with_params(inertia=small_tree.inertia * s)  # noqa: E731
            on_model = lambda s: forward_dynamics(scaled(s), *states, smooth_friction=0.1)  # noqa: E731
            jax.jit(on_model)(1.0), jax.vmap(on_model)(jnp.ones(2)), jax.grad(lambda s: jnp.sum(on_model(s)))(1.0)
        assert chosen == [int(np.prod(lead)) <= n] + [False] * 5, lead
        assert out.shape == q.shape
        flat = [x.reshape(-1, n) for x in (q, qd, tau)]
        assert max_rel(out.reshape(-1, n), one(*flat)) <= SAME_RTOL
        with _sweeps_seen() as widths:  # the loop itself: no sweeps, the same values
            looped = jax.jit(lambda a, b, c: dynamics._batched.raw(small_tree, a, b, c, 0.1, True))(q, qd, tau)
        assert not widths and max_rel(looped.reshape(-1, n), one(*flat)) <= SAME_RTOL


def test_loop_sweeps_equal_written_out_sweeps_and_differentiate(small_tree, tiny_tree):
    """The scan-over-links sweeps (trees beyond UNROLL_LINKS) on small trees, against the written-out sweeps (values,
    with prismatic joints, rotor inertia and a branch) and against finite differences (gradients, fwd and rev)."""
    from particlesim.tree import aba as aba_module

    rng = np.random.default_rng(12)
    n = small_tree.nq
    q, qd, tau = (jnp.asarray(rng.normal(size=(n, 3))) for _ in range(3))
    loop = jax.jit(lambda m, q, qd, t: aba_module._aba_loop(m, q, qd, t))
    written = jax.jit(lambda m, q, qd, t: aba_module._aba_unrolled(m, q, qd, t))
    with jax.numpy_rank_promotion("allow"):
        assert max_rel(loop(small_tree, q, qd, tau), written(small_tree, q, qd, tau)) <= SAME_RTOL
        x = (jnp.asarray(rng.normal(size=(tiny_tree.nq, 2))) for _ in range(3))
        check_grads(lambda *a: loop(tiny_tree, *a), tuple(x), order=1, modes=("fwd", "rev"))


def test_one_state_loop_sweeps_equal_written_out_sweeps_and_differentiate(small_tree, tiny_tree):
    """The one-state layout of the sweeps (trees beyond UNROLL_LINKS: small loops for the recursions, link terms
    vectorised over links) on small trees, against the written-out sweeps state by state (values) and against finite
    differences (gradients w.r.t. the state and the inertial parameters, fwd and rev)."""
    from particlesim.tree import aba as aba_module

    rng = np.random.default_rng(13)
    n = small_tree.nq
    one = jax.jit(aba_module.aba_one_state)
    written = jax.jit(lambda m, q, qd, t: aba_module._aba_unrolled(m, q[:, None], qd[:, None], t[:, None])[:, 0])
    for _ in range(3):
        q, qd, tau = (jnp.asarray(rng.normal(size=n)) for _ in range(3))
        with jax.numpy_rank_promotion("allow"):
            ref = written(small_tree, q, qd, tau)
        assert max_rel(one(small_tree, q, qd, tau), ref) <= SAME_RTOL
    x = tuple(jnp.asarray(rng.normal(size=tiny_tree.nq)) for _ in range(3))
    check_grads(lambda q, qd, t, p: one(tiny_tree.with_params(inertia=p), q, qd, t), x + (tiny_tree.inertia,),
                order=1, modes=("fwd", "rev"))


def test_deep_small_tree_single_state_takes_the_sweeps_and_matches_pinocchio():
    """A 20-link serial chain (mean link depth 10.5, below UNROLL_LINKS) takes the one-state sweeps; against
    Pinocchio's ABA on random states, and equal to the composite-inertia solve it replaces."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    from benchmarks.tree_scaling import chain_urdf
    from particlesim.tree import aba as aba_module
    from particlesim.tree.dynamics import _bodies, _mass_matrix, _rnea

    urdf = chain_urdf(20, seed=3)
    gravity = (0.0, 0.0, -9.81)
    model = load_urdf(urdf, gravity=gravity)
    assert model.nq <= UNROLL_LINKS and aba_module.one_state_sweeps(model)
    oracle = PinocchioOracle(urdf, model.joint_names, gravity)
    rng = np.random.default_rng(14)
    fd = jax.jit(forward_dynamics)

    def composite(m, q, qd, tau):
        b = _bodies(m, q)
        return jnp.linalg.solve(_mass_matrix(m, b), tau - _rnea(m, b, qd, None, m.gravity))

    composite = jax.jit(composite)
    for _ in range(3):
        q, qd, tau = rng.uniform(-2.0, 2.0, model.nq), rng.normal(size=model.nq), rng.normal(size=model.nq)
        ours = np.asarray(fd(model, q, qd, tau))
        assert max_rel(ours, _pin_aba(oracle, q[None], qd[None], tau[None])[0]) <= PIN_RTOL
        assert max_rel(ours, composite(model, q, qd, tau)) <= PIN_RTOL


def test_wide_batches_take_the_wide_entry(tiny_tree, monkeypatch):
    """From WIDE_BATCH states on (deep trees up to UNROLL_LINKS links; here the tiny tree treated as deep) a batch
    goes to the wide entry: the same program compiled with the batch options alone (XLA's fusion emitters kept). The
    choice by size (fails if the sizes are swapped or the wide entry is never taken), its values against one state at
    a time, and its compiler options."""
    from particlesim._xla import cpu_options
    from particlesim.tree import aba as aba_module, dynamics

    monkeypatch.setattr(aba_module, "SHALLOW_DEPTH", 0)
    monkeypatch.setattr(aba_module, "BATCH_THREADS", 1)  # one program (parts go through _batched_part)
    n = tiny_tree.n_joints
    wide = aba_module.WIDE_BATCH
    assert [aba_module.wide_batch(s, n) for s in (wide - 1, wide, 4096)] == [False, True, True]
    assert not aba_module.wide_batch(4096, UNROLL_LINKS + 1)  # looped sweeps: chunks of at most 88 states
    rng = np.random.default_rng(18)
    q, qd, tau = (jnp.asarray(rng.normal(size=(wide, n))) for _ in range(3))
    chosen = []
    with pytest.MonkeyPatch.context() as mp:
        for name in ("_batched", "_batched_wide"):
            mp.setattr(dynamics, name, lambda *a, name=name: chosen.append(name) or jnp.zeros(a[1].shape))
        forward_dynamics(tiny_tree, q[:-1], qd[:-1], tau[:-1])
        forward_dynamics(tiny_tree, q, qd, tau)
    assert chosen == ["_batched", "_batched_wide"]
    out = forward_dynamics(tiny_tree, q, qd, tau, smooth_friction=0.1)
    one = jax.jit(jax.vmap(lambda a, b, c: forward_dynamics(tiny_tree, a, b, c, smooth_friction=0.1)))
    assert max_rel(out, one(q, qd, tau)) <= SAME_RTOL
    assert dynamics._batched_wide.jit.top_options == cpu_options(batch="wide")
    if jax.default_backend() == "cpu":  # set per program: the suite's XLA_FLAGS turn the fusion emitters off
        from particlesim._xla import BATCH_OPTIONS, COMPILE_OPTIONS

        assert cpu_options(batch="wide") == {"xla_cpu_use_fusion_emitters": True, **BATCH_OPTIONS}
        assert cpu_options(batch=True) == {**COMPILE_OPTIONS, **BATCH_OPTIONS}
    with pytest.raises(ValueError, match="batch must be"):
        cpu_options(batch="Wide")


def test_wide_batches_of_models_outside_the_sweeps_stay_on_the_batch_entry(monkeypatch):
    """A floating-base model (no sweeps) evaluates even a wide batch state by state through the batch entry (the
    tree treated as deep, so that its batch would otherwise be wide)."""
    from particlesim.tree import aba as aba_module, dynamics

    monkeypatch.setattr(aba_module, "SHALLOW_DEPTH", 0)
    monkeypatch.setattr(aba_module, "BATCH_THREADS", 1)
    urdf = random_tree_urdf(4, 2).replace('<link name="base"/>', '<link name="base"><inertial><mass value="2"/>'
                                          '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.15"/>'
                                          '</inertial></link>')
    model = load_urdf(urdf, floating_base=True, limits="ignore")
    assert not supports_aba(model)
    assert aba_module.wide_batch(aba_module.WIDE_BATCH, model.n_joints, aba_module.tree_depth(model.parents))
    q = jnp.tile(jnp.concatenate([jnp.zeros(3), jnp.array([0.0, 0.0, 0.0, 1.0]), jnp.zeros(model.nq - 7)]),
                 (aba_module.WIDE_BATCH, 1))
    v = jnp.zeros((aba_module.WIDE_BATCH, model.nv))
    chosen = []
    with pytest.MonkeyPatch.context() as mp:
        for name in ("_batched", "_batched_wide"):
            mp.setattr(dynamics, name, lambda *a, name=name: chosen.append(name) or jnp.zeros(a[2].shape))
        forward_dynamics(model, q, v, v)
    assert chosen == ["_batched"]



def test_batch_parts_by_cores_and_work(monkeypatch):
    """One part per usable core, as far as each part keeps PART_LINK_STATES link-states; BATCH_THREADS overrides the
    core count (1: one program)."""
    from particlesim.tree import aba as aba_module

    per = aba_module.PART_LINK_STATES
    monkeypatch.setattr(aba_module, "usable_cores", lambda: 2)
    assert [aba_module.batch_parts(s, 18) for s in (0, 1, 2 * per // 18 - 1, 2 * per // 18 + 1, 1024)] \
        == [1, 1, 1, 2, 2]
    monkeypatch.setattr(aba_module, "usable_cores", lambda: 1)
    assert aba_module.batch_parts(4096, 18) == 1
    monkeypatch.setattr(aba_module, "BATCH_THREADS", 3)
    assert [aba_module.batch_parts(s, 200) for s in (10, 20, 31, 4096)] == [1, 1, 3, 3]
    assert aba_module.usable_cores() >= 1


@pytest.mark.parametrize("threads", [2, 3, 25])
def test_batches_split_over_threads(small_tree, threads, monkeypatch):
    """A batch passed from Python runs in parts on as many threads (the first on this one, the others each on a
    worker thread of its own): 70 states over leading axes (2, 35), broadcast from ``qd`` of shape (35, n), in 2 parts of 35, 3 of
    24 (the last starting at state 46, its first two states dropped), or for 25 threads 24 parts of 3 (25 parts of
    3 would start two at state 67). The same values as one program and as state by
    state, the batch's shape kept; the parts' program traced once, also for new states and parameter values; inside a
    caller's trace the batch is one program."""
    from particlesim import _ode
    from particlesim.tree import aba as aba_module, dynamics

    monkeypatch.setattr(aba_module, "PART_LINK_STATES", 1)
    n = small_tree.nq
    rng = np.random.default_rng(21)
    q, tau = (jnp.asarray(rng.normal(size=(2, 35, n))) for _ in range(2))
    qd = jnp.asarray(rng.normal(size=(35, n)))
    monkeypatch.setattr(aba_module, "BATCH_THREADS", 1)
    whole = forward_dynamics(small_tree, q, qd, tau, smooth_friction=0.1)
    monkeypatch.setattr(aba_module, "BATCH_THREADS", threads)
    assert aba_module.batch_parts(70, small_tree.n_joints) == threads
    ran = []
    real_run_parts = dynamics.run_parts

    def spy(fn, parts, **kwargs):
        def part(*args):
            ran.append((threading.current_thread().name, args[4].item()))
            return fn(*args)
        return real_run_parts(part, parts, **kwargs)

    monkeypatch.setattr(dynamics, "run_parts", spy)
    name = "forward_dynamics batch part"
    before = _ode.TRACES[name]
    out = forward_dynamics(small_tree, q, qd, tau, smooth_friction=0.1)
    assert out.shape == (2, 35, n)
    count = -(-70 // threads)
    parts = -(-70 // count)
    assert parts == (24 if threads == 25 else threads)
    assert sorted(s for _, s in ran) == [min(i * count, 70 - count) for i in range(parts)]
    main = threading.current_thread().name
    assert [t for t, s in ran if s == 0] == [main]  # the first part dispatched on this thread
    assert len({t for t, _ in ran}) == parts and all(t.startswith("particlesim-part") for t, s in ran if s != 0)
    assert max_rel(out, whole) <= SAME_RTOL

    def by_state(model):
        fd = jax.vmap(lambda a, b, c: forward_dynamics(model, a, b, c, smooth_friction=0.1))
        return jax.jit(jax.vmap(fd, in_axes=(0, None, 0)))

    assert max_rel(out, by_state(small_tree)(q, qd, tau)) <= SAME_RTOL
    assert _ode.TRACES[name] - before == 1  # threads running their parts at once compiled one program
    heavier = small_tree.with_params(inertia=small_tree.inertia * 1.3)
    out2 = forward_dynamics(heavier, q + 0.1, qd, tau, smooth_friction=0.1)
    assert _ode.TRACES[name] - before == 1
    assert max_rel(out2, by_state(heavier)(q + 0.1, qd, tau)) <= SAME_RTOL
    ran.clear()
    inside = jax.jit(lambda a, b, c: forward_dynamics(small_tree, a, b, c, smooth_friction=0.1))(q, qd, tau)
    assert not ran and max_rel(inside, whole) <= SAME_RTOL


def test_parts_nested_in_parts_do_not_wait_on_themselves():
    """A part that itself starts a batch in parts (as a program calling back into Python could): the nested parts
    get worker threads of their own rather than waiting for their parents', so nesting finishes (a watchdog thread
    bounds the wait)."""
    from particlesim._threads import run_parts

    def part(depth):
        return 1 if depth == 0 else sum(run_parts(part, [(depth - 1,), (depth - 1,)]))

    out = []
    t = threading.Thread(target=lambda: out.append(run_parts(part, [(3,), (3,)])), daemon=True)
    t.start()
    t.join(timeout=60)
    assert out == [[8, 8]]
