"""Linearisation: exact Jacobians vs finite differences of the numpy plant, trims are equilibria, structure."""
import numpy as np
import pytest

from udrobot_ctrl.control import linearize as L
from udrobot_ctrl.dynamics.plant import state_derivative, thrust_to_wrench
from udrobot_ctrl.dynamics.sim import as_parameters

MODELS = ("cfd:chin", "free_decay:morison")


def numpy_f(p, x, f):
    return state_derivative(x, thrust_to_wrench(f, p, clip=False), p)


@pytest.mark.parametrize("name", MODELS)
def test_jacobians_match_finite_differences_of_numpy_plant(name):
    p = as_parameters(name)
    rng = np.random.default_rng(1)
    x = np.concatenate([[0.3, -0.2, 1.0, 0.1, -0.05, 0.7], [0.4, 0.05, -0.1, 0.05, 0.02, -0.1]])
    f = rng.uniform(-5, 5, 4)
    f0, A, B = L.jacobians(p, x, f)
    assert np.allclose(f0, numpy_f(p, x, f), atol=1e-9)
    h = 1e-6
    A_fd = np.column_stack([(numpy_f(p, x + h * e, f) - numpy_f(p, x - h * e, f)) / (2 * h) for e in np.eye(12)])
    B_fd = np.column_stack([(numpy_f(p, x, f + h * e) - numpy_f(p, x, f - h * e)) / (2 * h) for e in np.eye(4)])
    assert np.allclose(A, A_fd, atol=1e-6, rtol=1e-6)
    assert np.allclose(B, B_fd, atol=1e-8)


@pytest.mark.parametrize("name", MODELS)
def test_trims_are_equilibria(name):
    p = as_parameters(name)
    hover = L.hover_trim(p, depth=1.0)
    # the vertical thrusters hold the net buoyancy B - W (positively buoyant vehicle: push down)
    assert np.isclose(hover.u0[2] + hover.u0[3], p.buoyancy - p.weight, atol=1e-9)
    assert hover.is_equilibrium
    assert np.max(np.abs(numpy_f(p, hover.x0, hover.u0))) < 1e-9
    pts = L.operating_points(p)
    assert [round(pt.surge, 2) for pt in pts[:3]] == [0.0, 0.25, 0.5]
    vmax = pts[-1].surge
    assert 1.0 < vmax < 2.0
    # at the top speed the surge thrusters are at their forward limit
    assert np.allclose(pts[-1].u0[:2], p.f_max[:2], atol=1e-6)
    for pt in pts:
        assert pt.is_equilibrium, pt.name
        xdot = numpy_f(p, pt.x0, pt.u0)
        # a trim: depth, attitude and body velocities constant; x advances at the surge speed (NED, heading 0)
        assert np.max(np.abs(xdot[2:])) < 1e-8 and np.isclose(xdot[0], pt.surge) and abs(xdot[1]) < 1e-12


def test_state_space_object_and_structure():
    p = as_parameters("cfd:chin")
    lin = L.linearize(p, L.hover_trim(p), outputs=("z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r"))
    sys = lin.sys
    assert sys.nstates == 12 and sys.ninputs == 4 and sys.noutputs == 10
    assert list(sys.input_labels) == ["T1", "T2", "T3", "T4"]
    Ar, Br = lin.reduced()
    rep = L.structure_report(Ar, Br, states=L.REDUCED_STATES)
    assert rep.controllable_rank == 10 and rep.stabilizable
    # position x, y: pure integrators, unobservable from the reduced outputs
    full = L.structure_report(lin.A, lin.B, C=sys.C)
    assert full.observable_rank == 10
    # sway and pitch: only weakly controllable (no thruster acts on them directly)
    weak = {k for k, m in zip(rep.dominant_states, rep.pbh_margin) if m < 1e-2}
    assert any("theta" in rep.dominant_states[k] or "v" in rep.dominant_states[k] for k in weak)


def test_passive_modes_stable_or_marginal_and_munk_instability_reported():
    # Chin form (linear damping): passive modes strictly stable at hover
    p = as_parameters("cfd:chin")
    assert L.passive_modes(L.linearize(p, L.hover_trim(p)))["stable"]
    # Morison form: no linear damping -> marginal at hover (quadratic drag has zero slope at rest)
    q = as_parameters("free_decay:morison")
    pm = L.passive_modes(L.linearize(q, L.hover_trim(q)))
    assert pm["marginal"] and not pm["stable"]
    # at 0.5 m/s damping appears; at the top speed the Munk moment makes free_decay's pitch unstable
    assert L.passive_modes(L.linearize(q, L.trim_at(q, 0.5)))["stable"]
    top = L.operating_points(q)[-1]
    assert np.max(L.passive_modes(L.linearize(q, top))["eigenvalues"].real) > 0
