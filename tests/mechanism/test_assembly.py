"""Assembly from approximate positions, against the closed-form position analysis of a four-bar loop."""

import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.errors import ModelError
from particlesim.mechanism import assemble, constraints

#: Closed-form four-bar positions against the assembled ones [m].
POSITION_TOL = 1e-12
#: Largest constraint residual after assembly (distance rows are squared lengths) [m, m^2].
RESIDUAL_TOL = 1e-12


def _circle_intersection(a, ra, c, rc, near):
    """The intersection of the circles (a, ra) and (c, rc) in the plane nearest ``near`` (closed form)."""
    a, c = np.asarray(a, float), np.asarray(c, float)
    d = np.linalg.norm(c - a)
    along = (ra**2 - rc**2 + d**2) / (2 * d)
    h = np.sqrt(ra**2 - along**2)
    u = (c - a) / d
    base = a + along * u
    cands = [base + s * h * np.array([-u[1], u[0]]) for s in (1.0, -1.0)]
    return min(cands, key=lambda p: np.linalg.norm(p - near))


def test_builder_assembles_an_open_loop_holding_the_crank(four_bar):
    # rocker drawn 0.01 m too long: the loop is open by 0.01 m at B = B2
    mb = four_bar(offset=0.01)
    mech, x0 = mb.build(dof=3, assemble=True, hold=["A"])
    asm = mb.assembly
    assert np.abs(np.asarray(constraints(mech, jnp.asarray(x0)))).max() <= RESIDUAL_TOL
    r = {n: x0[mech.free_slice(n)] for n in ("A", "B", "B2")}
    np.testing.assert_array_equal(r["A"], [0.0, 1.0, 0.0])  # held exactly
    # coupler |AB| = 2 and rocker |C B2| = 1.01 as drawn: B is where the two circles meet
    expect = _circle_intersection((0, 1), 2.0, (2, 0), 1.01, near=(2, 1))
    np.testing.assert_allclose(r["B"][:2], expect, atol=POSITION_TOL)
    np.testing.assert_allclose(r["B2"], r["B"], atol=POSITION_TOL)
    assert abs(r["B"][2]) <= POSITION_TOL  # the in-plane correction stays in the plane
    assert list(asm.moved)[0] == "B" and asm.moved["B"] == pytest.approx(0.01, rel=1e-3)
    assert "A" not in asm.moved and asm.residual <= RESIDUAL_TOL


def test_unassembled_data_are_refused_with_the_way_out(four_bar):
    with pytest.raises(ModelError, match="violate constraints: loop closure.*assemble=True"):
        four_bar(offset=0.01).build()


def test_assemble_sets_a_crank_angle_and_the_loop_follows(four_bar):
    mech, x0 = four_bar().build(dof=3)
    for theta in (0.3, 1.2, 2.0):
        x = np.array(x0)
        x[mech.free_slice("A")] = (np.sin(theta), np.cos(theta), 0.0)  # crank |OA| = 1 turned by theta
        asm = assemble(mech, x, hold=["A"])
        assert asm.residual <= RESIDUAL_TOL
        a = asm.q[mech.free_slice("A")]
        np.testing.assert_array_equal(a, x[mech.free_slice("A")])
        expect = _circle_intersection(a[:2], 2.0, (2, 0), 1.0, near=(2, 1))
        np.testing.assert_allclose(asm.q[mech.free_slice("B")][:2], expect, atol=POSITION_TOL)
        np.testing.assert_allclose(asm.correction, asm.q - x)


def test_single_coordinates_can_be_held(four_bar):
    mech, x0 = four_bar(offset=0.01).build(dof=3, assemble=True, hold=[("B", "x"), ("B", "z")])
    np.testing.assert_array_equal(x0[mech.free_slice("B")][[0, 2]], [2.0, 0.0])


def test_a_loop_that_cannot_close_is_reported(four_bar):
    # rocker 0.1 m: coupler + rocker (2.1 m) cannot reach from the held crank tip to the rocker pivot (2.24 m)
    with pytest.raises(ModelError, match="assembly failed.*held coordinates.*largest residuals"):
        four_bar(offset=-0.9).build(assemble=True, hold=["A"])


@pytest.mark.parametrize("hold, match", [(["O"], "cannot hold 'O': a ground particle"),
                                         (["nowhere"], "cannot hold 'nowhere': not a particle"),
                                         ([("A", "w")], "the axis must be")])
def test_bad_holds(hold, match, four_bar):
    mech, x0 = four_bar().build()
    with pytest.raises(ModelError, match=match):
        assemble(mech, x0, hold=hold)


def test_bad_state(four_bar):
    mech, x0 = four_bar().build()
    with pytest.raises(ModelError, match="q must be 9 finite numbers"):
        assemble(mech, np.full(9, np.nan))
    with pytest.raises(ModelError, match="q must be 9 finite numbers"):
        assemble(mech, x0[:6])
