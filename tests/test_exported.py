"""Programs kept across processes (bayesdoor._exported): the same numbers, no second trace,
and a key that changes with everything that would change the trace."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesdoor import _exported
from bayesdoor._exported import FALLBACKS, persistent_jit

TRACES: list[str] = []


class Settings(eqx.Module):
    power: int = eqx.field(static=True)
    offset: jax.Array


@persistent_jit
def toy(x, scale: float, settings: Settings):
    TRACES.append("toy")
    return {"y": x**settings.power * scale + settings.offset, "total": jnp.sum(x)}


class Output(eqx.Module):
    values: jax.Array
    label: str = eqx.field(static=True)
    scale: float = 1.0


@persistent_jit
def as_module(x):
    return Output(values=x + 1.0, label="shifted", scale=2.0)


@persistent_jit
def checked(x):
    TRACES.append("checked")
    return eqx.error_if(x, x < 0, "negative")  # a host callback: jax.export refuses it


@dataclasses.dataclass(frozen=True)
class Foreign:
    """A type of a user's other module (its source may change between processes, and the
    key does not hold it)."""

    factor: float


Foreign.__module__ = "someone_elses_code"


@persistent_jit
def with_foreign(x, foreign: Foreign):
    return x * foreign.factor


@pytest.fixture
def kept(tmp_path, monkeypatch):
    """An empty folder of kept programs, nothing loaded in this process."""
    before = getattr(jax.config, "jax_compilation_cache_dir", None)
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))
    monkeypatch.setattr(_exported, "_LOADED", {})
    monkeypatch.delenv("BAYESDOOR_EXPORTED", raising=False)
    TRACES.clear()
    yield tmp_path / _exported.FOLDER
    jax.config.update("jax_compilation_cache_dir", before)


def _new_process(monkeypatch) -> None:
    """What a new process finds: nothing loaded, the folder as it is."""
    monkeypatch.setattr(_exported, "_LOADED", {})


def test_a_kept_program_gives_the_same_numbers_and_is_read_back_untraced(kept, monkeypatch):
    x = jnp.linspace(0.0, 1.0, 7)
    settings = Settings(power=3, offset=jnp.asarray(0.5))
    first = toy(x, 2.0, settings)
    assert TRACES == ["toy"]
    assert len(list(kept.glob("*.bin"))) == 1
    reference = toy.jitted(x, 2.0, settings)
    for k in ("y", "total"):
        np.testing.assert_array_equal(np.asarray(first[k]), np.asarray(reference[k]))
    TRACES.clear()

    _new_process(monkeypatch)
    again = toy(np.asarray(x), 2.0, settings)  # numpy arrays are traced as JAX arrays are
    assert TRACES == []
    for k in ("y", "total"):
        np.testing.assert_array_equal(np.asarray(again[k]), np.asarray(first[k]))


def test_a_module_returned_is_rebuilt_in_a_new_process(kept, monkeypatch):
    first = as_module(jnp.arange(3.0))
    _new_process(monkeypatch)
    again = as_module(jnp.arange(3.0))
    assert isinstance(again, Output) and (again.label, again.scale) == ("shifted", 2.0)
    np.testing.assert_array_equal(np.asarray(again.values), np.asarray(first.values))


def test_the_key_follows_static_values_shapes_and_dtypes(kept):
    x = jnp.linspace(0.0, 1.0, 7)
    settings = Settings(power=3, offset=jnp.asarray(0.5))
    toy(x, 2.0, settings)
    toy(x, 3.0, settings)  # a static float
    toy(x, 2.0, Settings(power=2, offset=jnp.asarray(0.5)))  # a static field
    toy(x[:5], 2.0, settings)  # a shape
    toy(x.astype(jnp.float32), 2.0, settings)  # a dtype
    toy(x, 2.0, Settings(power=3, offset=jnp.asarray(9.0)))  # a traced value: same program
    assert len(TRACES) == 5
    assert len(list(kept.glob("*.bin"))) == 5
    out = toy(x, 2.0, Settings(power=2, offset=jnp.asarray(9.0)))
    np.testing.assert_allclose(np.asarray(out["y"]), np.asarray(x) ** 2 * 2.0 + 9.0)


def test_foreign_types_and_tracers_are_traced_as_usual(kept):
    x = jnp.arange(3.0)
    FALLBACKS.clear()
    np.testing.assert_array_equal(np.asarray(with_foreign(x, Foreign(2.0))), [0.0, 2.0, 4.0])
    assert not kept.exists() or not list(kept.glob("*.bin"))
    assert any("Foreign" in reason for _, reason in FALLBACKS)

    settings = Settings(power=1, offset=jnp.asarray(0.0))
    grad = jax.grad(lambda v: toy(v, 2.0, settings)["y"].sum())(x)
    np.testing.assert_allclose(np.asarray(grad), 2.0)
    assert any(reason == "tracer" for _, reason in FALLBACKS)


def test_a_program_with_a_host_callback_is_traced_as_usual(kept, monkeypatch):
    np.testing.assert_array_equal(np.asarray(checked(jnp.arange(3.0))), [0.0, 1.0, 2.0])
    assert TRACES == ["checked", "checked"]  # the refused export, then eqx.filter_jit's
    assert [p.suffix for p in kept.iterdir()] == [".skip"]
    with pytest.raises(Exception, match="negative"):
        checked(-jnp.arange(1.0, 3.0))
    _new_process(monkeypatch)
    exports = []
    export = _exported._export
    monkeypatch.setattr(_exported, "_export", lambda *a: exports.append(1) or export(*a))
    np.testing.assert_array_equal(np.asarray(checked(jnp.arange(3.0))), [0.0, 1.0, 2.0])
    assert exports == []  # the marker spares a later process the refused export


def test_switched_off_by_the_environment(kept, monkeypatch):
    monkeypatch.setenv("BAYESDOOR_EXPORTED", "0")
    toy(jnp.arange(3.0), 2.0, Settings(power=1, offset=jnp.asarray(0.0)))
    assert not kept.exists()


def test_the_door_solve_is_kept_with_identical_signals(kept, monkeypatch):
    from bayesdoor.door import (
        DoorDamage,
        DoorParameters,
        SolverConfig,
        _simulate,
        make_args,
        sample_times,
    )

    values = {k: jnp.stack([v, v]) for k, v in DoorParameters.paper_optimum().to_dict().items()}
    values["K"] = jnp.asarray([1800.0, 2000.0])
    batch = DoorParameters(**values)
    damage = jax.tree_util.tree_map(lambda v: jnp.stack([v, v]), DoorDamage.healthy())
    args = jax.vmap(lambda p, d: make_args(p, d, jnp.asarray(0.3)))(batch, damage)
    ts = sample_times(0.4)
    config = SolverConfig()
    signals, status = _simulate.solve_batch(args, ts, config)
    assert len(list(kept.glob("*.bin"))) == 1
    ref_signals, ref_status = _simulate.solve_batch.jitted(args, ts, config)
    np.testing.assert_array_equal(np.asarray(signals), np.asarray(ref_signals))
    np.testing.assert_array_equal(np.asarray(status), np.asarray(ref_status))

    traced = []
    solve = _simulate.solve
    monkeypatch.setattr(_simulate, "solve", lambda *a, **k: traced.append(1) or solve(*a, **k))
    _new_process(monkeypatch)
    again, _ = _simulate.solve_batch(args, ts, config)
    assert traced == []
    np.testing.assert_array_equal(np.asarray(again), np.asarray(signals))


_KEY_SCRIPT = """
import json, jax, jax.numpy as jnp
from bayesdoor._exported import _key
from bayesdoor.door import DoorDamage, DoorParameters, SolverConfig, make_args, sample_times
from bayesdoor.door._simulate import solve_batch
args = make_args(DoorParameters.paper_optimum(), DoorDamage.healthy(), jnp.asarray(0.3))
print(json.dumps(_key(solve_batch.__wrapped__, (args, sample_times(0.5), SolverConfig()), {})))
"""


def test_the_key_is_the_same_in_another_process():
    keys = [
        json.loads(
            subprocess.run(
                [sys.executable, "-c", _KEY_SCRIPT], capture_output=True, text=True, check=True
            ).stdout
        )
        for _ in range(2)
    ]
    assert keys[0] == keys[1]
