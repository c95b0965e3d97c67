"""Result codes and messages through equinox's public API (lionjax._errors)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import lionjax as lj

MEMBERS = ("successful", "unidentifiable", "unstable_step", "nonfinite")


def test_codes_and_messages_of_every_member():
    for name in MEMBERS:
        item = getattr(lj.RESULTS, name)
        code = lj.solutions.result_codes(item)
        assert code.shape == () and np.issubdtype(code.dtype, np.integer)
        assert lj.solutions.result_message(code) == lj.RESULTS[item]  # equinox's public lookup
    assert lj.solutions.result_message(lj.solutions.result_codes(lj.RESULTS.successful)) == ""
    codes = [int(lj.solutions.result_codes(getattr(lj.RESULTS, n))) for n in MEMBERS]
    assert sorted(codes) == list(range(len(lj.RESULTS)))


def test_code_under_jit_and_vmap():
    pick = lambda p: lj.RESULTS.where(p, lj.RESULTS.successful, lj.RESULTS.nonfinite)
    batched = jax.vmap(pick)(jnp.array([True, False, True]))
    bad = int(lj.solutions.result_codes(lj.RESULTS.nonfinite))
    np.testing.assert_array_equal(lj.solutions.result_codes(batched), [0, bad, 0])
    traced = eqx.filter_jit(lambda p: lj.solutions.result_code(pick(p)) * 2)(jnp.array(False))
    assert int(traced) == 2 * bad


def test_other_enumerations_and_bad_codes():
    code = lj.solutions.result_codes(optx.RESULTS.max_steps_reached)
    assert (
        lj.solutions.result_message(code, optx.RESULTS)
        == optx.RESULTS[optx.RESULTS.max_steps_reached]
    )
    for bad in (len(lj.RESULTS), -1, 1.0, np.array([0, 1])):
        with pytest.raises(lj.InputError, match="code"):
            lj.solutions.result_message(bad)
    with pytest.raises(TypeError, match="Enumeration"):
        lj.solutions.result_code(np.zeros(2))
