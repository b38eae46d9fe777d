"""Contact laws against hand-computed values, smoothing, latch, friction and restitution."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesdoor.contact import (
    CONTACT_LAWS,
    get_law,
    hysteresis_factor,
    latch_rate,
    single_impact,
    smooth_contact_force,
    stribeck_friction,
)

# hand values of xi at c_r = 0.7 from the formulas of DESIGN.md section 3
XI_AT_07 = {
    1: 0.3 / 0.7,  # (1 - c_r) / c_r
    2: 6 * 0.3 / (0.4**2 + 3),  # 6 (1 - c_r) / ((2 c_r - 1)^2 + 3)
    3: 8 * 0.3 / 3.5,  # 8 (1 - c_r) / (5 c_r)
    4: 0.75 * 0.3,
    5: 1.5 * 0.3,
    6: 0.75 * 0.51,  # 3 (1 - 0.49) / 4
    7: 0.75 * 0.51 * np.exp(0.6),
    8: 0.51 / 0.7,
    9: 1.5 * 0.3 / 0.7,
}


@pytest.mark.parametrize("index", range(1, 10))
def test_force_against_hand_values(index):
    # K = 1000 N/m^1.5, d = 1e-2 m -> K d^1.5 = 1 N; d_dot = 0.05, d_dot_minus = 0.1
    law = get_law(index)
    force = float(law.force(jnp.asarray(1e-2), 0.05, 0.1, 1000.0, 1.5, jnp.asarray(0.7)))
    assert force == pytest.approx(1.0 + XI_AT_07[index] * 0.5, rel=1e-12)


def test_traced_index_selects_the_same_factor_under_jit_and_vmap():
    c_r = jnp.linspace(0.6, 0.95, 9)
    idx = jnp.arange(1, 10)
    batched = jax.jit(jax.vmap(hysteresis_factor))(idx, c_r)
    expected = [law.hysteresis_factor(c) for law, c in zip(CONTACT_LAWS, c_r, strict=True)]
    np.testing.assert_allclose(batched, np.asarray(expected), rtol=1e-14)


def test_laws_by_name_and_index():
    assert get_law("lankarani_nikravesh").index == 6
    assert get_law("Hunt-Crossley").index == 5
    assert get_law(6).name == "lankarani_nikravesh"
    for bad, message in ((0, "out of range: allowed 1-9"), (10, "out of range"), ("x", "unknown")):
        with pytest.raises(ValueError, match=message):
            get_law(bad)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_smoothed_force_is_finite_with_finite_gradients_around_first_contact(dtype):
    def force(d, d_dot, k, n, xi):
        return smooth_contact_force(d, d_dot, jnp.asarray(0.05, dtype), k, n, xi)

    grad = jax.grad(force, argnums=(0, 1, 2, 3, 4))
    for d in (-1e-3, -1e-6, 0.0, 1e-9, 1e-6, 1e-4):
        args = [jnp.asarray(x, dtype) for x in (d, -0.02, 1e9, 1.93, 0.4)]
        assert np.isfinite(float(force(*args)))
        assert force(*args) >= 0
        assert all(np.isfinite(float(g)) for g in grad(*args))


def test_smoothed_force_equals_textbook_force_in_contact_and_is_never_tensile():
    law = get_law(6)
    xi = law.hysteresis_factor(jnp.asarray(0.7))
    d, d_dot, ddm = jnp.asarray(3e-4), jnp.asarray(0.02), jnp.asarray(0.1)
    smooth = smooth_contact_force(d, d_dot, ddm, 1e9, 1.5, xi)
    exact = law.force(d, d_dot, ddm, 1e9, 1.5, jnp.asarray(0.7))
    # 300 um against a 1 um smoothing width: exp(-300) corrections, round-off remains
    assert float(smooth) == pytest.approx(float(exact), rel=1e-9)
    # fast separation would make the raw damping term pull; the smoothed force does not
    assert float(smooth_contact_force(d, jnp.asarray(-1.0), ddm, 1e9, 1.5, xi)) >= 0


def test_latch_tracks_while_apart_and_freezes_in_contact():
    latch = jnp.asarray(0.0)
    assert float(latch_rate(jnp.asarray(-1e-3), 0.2, latch)) == pytest.approx(0.2 / 2e-3)
    assert abs(float(latch_rate(jnp.asarray(1e-4), 0.2, latch))) < 1e-30


def test_friction_follows_the_stribeck_curve_and_opposes_motion():
    def force(v):
        return float(stribeck_friction(jnp.asarray(v * v), 10.0, 0.8, 0.6) * v)

    assert force(0.003) == pytest.approx(-10 * 0.8 * np.exp(-0.09) - 10 * 0.0, rel=0.1)
    assert force(1.0) == pytest.approx(-6.0, rel=1e-3)  # mu_d beyond v_s
    assert force(-1.0) == pytest.approx(6.0, rel=1e-3)
    assert abs(force(0.0)) == 0.0
    vs = np.linspace(-1e-3, 1e-3, 201)
    assert np.all(np.abs(np.diff([force(v) for v in vs])) < 0.2)  # continuous through zero


def test_delivered_restitution_follows_the_literature():
    flores = [single_impact(3, c) for c in (0.7, 0.9)]
    np.testing.assert_allclose(flores, [0.7, 0.9], rtol=0.03)  # designed for the full range
    ln_low, ln_high = single_impact(6, 0.5), single_impact(6, 0.9)
    assert ln_low > 0.6  # Lankarani-Nikravesh is valid only as c_r -> 1
    assert ln_high == pytest.approx(0.9, rel=0.02)
    for law in CONTACT_LAWS:
        e = [single_impact(law.index, c) for c in (0.5, 0.7, 0.9)]
        assert e[0] < e[1] < e[2]
    # delivered restitution depends only on xi and n, not on K, mass or impact speed
    a = single_impact(8, 0.7, K=1e9, mass=1.0, v_in=0.1)
    b = single_impact(8, 0.7, K=3e6, mass=40.0, v_in=0.7)
    assert a == pytest.approx(b, rel=1e-6)
