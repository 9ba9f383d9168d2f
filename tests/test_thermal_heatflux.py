"""Heat flux from surface temperature (selfillum.thermal.heatflux) against closed forms (a
step and a ramp in heat flux on a semi-infinite body) and against an independent solver (a
finite-volume method of lines integrated by scipy.integrate.solve_ivp) for a thin
insulating layer on a metal base; bad substrate files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from resection.errors import InputError
from selfillum.thermal.heatflux import (
    Layer,
    Substrate,
    fill_gaps,
    heat_flux,
    read_substrate,
    step_response,
)

PEEK = Layer(1300.0, 1100.0, 0.25)
E = PEEK.effusivity
DT, N = 0.02, 400
t = np.arange(N) * DT


@pytest.mark.parametrize("method", ["cook-felderman", "impulse"])
def test_step_and_ramp_on_a_semi_infinite_body(method):
    sub = Substrate(PEEK)
    q0 = 2.5e4
    # a step at t = 0: T = 2 q sqrt(t) / (sqrt(pi) e)
    T = 300.0 + 2.0 * q0 * np.sqrt(t) / (np.sqrt(np.pi) * E)
    q = heat_flux(np.column_stack([T, T]), DT, sub, method)
    assert np.max(np.abs(q[6:] / q0 - 1.0)) < 0.01
    # a ramp q = a t: T = 4 a t^1.5 / (3 sqrt(pi) e)
    a = 1.0e4
    T = 300.0 + 4.0 * a * t**1.5 / (3.0 * np.sqrt(np.pi) * E)
    q = heat_flux(T[:, None], DT, sub, method)[:, 0]
    assert np.max(np.abs(q[6:] / (a * t[6:]) - 1.0)) < 0.01
    if method == "impulse":  # a flux linear between frames is recovered exactly
        np.testing.assert_allclose(q[1:], a * t[1:], rtol=1e-9)


def _fv_surface_temperature(layers, base, depth, q_of_t, times):
    """Surface temperature of layers on a base (insulated at ``depth``) under the surface
    heat flux ``q_of_t``: finite volumes (cells graded geometrically from 0.2 um at the
    surface and at each interface), BDF by solve_ivp; T at the surface extrapolated from
    the first cell with the flux."""
    from scipy.integrate import solve_ivp
    from scipy.sparse import diags

    edges = [0.0]
    mats = []
    for lay in [*layers, base]:
        L = lay.thickness if lay.thickness is not None else depth - edges[-1]
        h, x, cells = 2e-7, 0.0, []
        while x + h < L:
            cells.append(h)
            x += h
            h = min(h * 1.15, L / 4)
        cells[-1] += L - x
        for c in cells:
            edges.append(edges[-1] + c)
            mats.append(lay)
    dx = np.diff(edges)
    k = np.array([m.k for m in mats])
    rc = np.array([m.rho * m.c for m in mats])
    # conductance between neighbouring cells (half-cells in series)
    G = 1.0 / (0.5 * dx[:-1] / k[:-1] + 0.5 * dx[1:] / k[1:])
    cap = rc * dx
    main = np.zeros(len(dx))
    main[:-1] -= G
    main[1:] -= G
    A = diags([main / cap, G / cap[:-1], G / cap[1:]], [0, 1, -1], format="csr")
    b0 = 1.0 / cap[0]

    def rhs(_t, y):
        out = A @ y
        out[0] += b0 * q_of_t(_t)
        return out

    sol = solve_ivp(rhs, (0.0, times[-1]), np.zeros(len(dx)), method="BDF", t_eval=times,
                    rtol=1e-9, atol=1e-12, jac=A, max_step=DT / 4)
    T1 = sol.y[0]
    return T1 + np.array([q_of_t(s) for s in times]) * 0.5 * dx[0] / k[0]


def test_layer_on_a_base_against_a_finite_volume_solve():
    layer = Layer(1200.0, 1500.0, 0.2, thickness=60e-6)  # an insulating paint layer
    steel = Layer(8000.0, 500.0, 16.0)
    sub = Substrate(steel, (layer,))
    n = 120
    times = np.arange(n) * DT
    q0 = 2.0e4

    def q_of_t(s):
        return q0 * (1.0 - np.exp(-s / 0.1)) * (1.0 + 0.3 * np.sin(2 * np.pi * 2.0 * s))

    depth = 0.02  # 20 mm: sqrt(alpha t) = 2 mm at the end, an insulated back 10 times deeper
    T = _fv_surface_temperature([layer], steel, depth, q_of_t, times)
    # the step response of the exact transfer function against the same solver's
    S = step_response(sub, times)
    S_fv = _fv_surface_temperature([layer], steel, depth, lambda s: 1.0, times)
    np.testing.assert_allclose(S[5:], S_fv[5:], rtol=2e-3)
    q = heat_flux(T[:, None], DT, sub, "impulse")[:, 0]
    q_true = np.array([q_of_t(s) for s in times])
    assert np.max(np.abs(q[6:] - q_true[6:])) / q0 < 0.01
    # Cook-Felderman with the base's effusivity alone misses the layer by far
    q_cf = heat_flux(T[:, None], DT, Substrate(steel), "cook-felderman")[:, 0]
    assert np.max(np.abs(q_cf[6:] - q_true[6:])) / q0 > 0.2


def test_finite_base_and_talbot_agree_with_the_closed_form():
    # a layer of the base's own material: the semi-infinite closed form
    sub = Substrate(PEEK, (Layer(PEEK.rho, PEEK.c, PEEK.k, 1e-4),))
    np.testing.assert_allclose(step_response(sub, t[1:]),
                               2 * np.sqrt(t[1:]) / (np.sqrt(np.pi) * E), rtol=1e-8)
    # a slab with an insulated back: the heat stored, q t = rho c L (T) at long times
    slab = Substrate(Layer(2700.0, 900.0, 200.0, thickness=1e-3))
    tl = np.array([2.0, 5.0])
    np.testing.assert_allclose(step_response(slab, tl), tl / (2700.0 * 900.0 * 1e-3)
                               + 1e-3 / (3 * 200.0), rtol=1e-6)


def test_gaps_are_filled_and_unseen_starts_are_refused():
    T = np.array([[1.0, np.nan, 1.0, 9.0], [2.0, 5.0, np.nan, 8.0],
                  [np.nan, 6.0, np.nan, 7.0], [4.0, 7.0, 4.0, 6.0]])
    f, ok = fill_gaps(T)
    np.testing.assert_allclose(f[:, 0], [1, 2, 3, 4])
    np.testing.assert_allclose(f[:, 2], [1, 2, 3, 4])
    np.testing.assert_array_equal(f[:, 3], [9, 8, 7, 6])  # seen throughout: as it is
    assert np.isnan(f[:, 1]).all()
    assert list(ok) == [True, False, True, True]
    f, ok = fill_gaps(T[:, 3:])  # no gap at all
    np.testing.assert_array_equal(f[:, 0], [9, 8, 7, 6])
    assert list(ok) == [True]


@pytest.mark.parametrize("d, words", [
    ({"rho": 1300, "c": 1100}, "missing k"),
    ({"rho": 1300, "c": -1, "k": 0.2}, "c = -1 must be positive"),
    ({"layers": [{"rho": 1, "c": 1, "k": 1}], "substrate": {"rho": 1, "c": 1, "k": 1}},
     "layer 1: a layer needs its thickness"),
    ({"layers": [{"rho": 1, "c": 1, "k": 1, "thickness": 1e-5}]}, "need the substrate"),
])
def test_bad_substrate_one_line(tmp_path, d, words):
    p = tmp_path / "S.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError) as ei:
        read_substrate(p)
    assert str(p) in str(ei.value) and words in str(ei.value)
