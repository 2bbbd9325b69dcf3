"""DecompositionConfig: each setting declared once, and KernelParams generated from the declarations."""

from __future__ import annotations

import dataclasses
import enum
import re
from pathlib import Path

import pytest

from fwcore.engine.config import (LOCAL_NONE, MEASURED_KERNEL_VALUES, OPTIMIZERS, PRESETS, DecompositionConfig,
                                  KernelParams, Model, Optimizer)

DEFAULT = DecompositionConfig()
FIELDS = dataclasses.fields(DecompositionConfig)


def kernel_params(config: DecompositionConfig) -> KernelParams:
    """The kernels' settings with the config's own model and a file's pulse of no shape tolerance."""
    return config.kernel_params(config.model, 0.0)


def other_value(name: str):
    """A valid value of the setting other than its default (the first candidate the config accepts)."""
    default = getattr(DEFAULT, name)
    if isinstance(default, bool):
        candidates = [not default]
    elif isinstance(default, enum.Enum):
        candidates = [m for m in type(default) if m is not default]
    elif isinstance(default, int):
        candidates = [default + 1]
    else:
        base = default or 0.0
        candidates = [base * 0.5, base * 1.5, base + 1.0, 0.5]
    for value in candidates:
        try:
            DEFAULT.replace(**{name: value})
        except ValueError:
            continue
        if value != default:
            return value
    raise AssertionError(f"no valid value of {name} besides its default")


@pytest.mark.parametrize("field", [f for f in FIELDS if f.metadata.get("kernel") is True], ids=lambda f: f.name)
def test_every_kernel_setting_reaches_kernel_params(field):
    value = other_value(field.name)
    assert getattr(kernel_params(DEFAULT.replace(**{field.name: value})), field.name) == value


@pytest.mark.parametrize("field", [f for f in FIELDS if callable(f.metadata.get("kernel"))], ids=lambda f: f.name)
def test_every_enum_setting_the_kernels_read_changes_kernel_params(field):
    seen = {kernel_params(DEFAULT.replace(**{field.name: member})) for member in type(getattr(DEFAULT, field.name))}
    assert len(seen) > 1


def test_kernel_params_hold_the_declared_settings_and_nothing_else():
    declared = set(MEASURED_KERNEL_VALUES)
    for field in FIELDS:
        kernel = field.metadata.get("kernel")
        if kernel is True:
            declared.add(field.name)
        elif kernel:
            declared |= set(kernel(getattr(DEFAULT, field.name)))
    assert set(KernelParams._fields) == declared


def test_every_kernel_param_is_read_by_a_kernel():
    # a field no kernel reads is a setting that does nothing
    source = "".join(p.read_text() for p in Path("fwcore").rglob("*.py") if p.name != "config.py")
    unread = [name for name in KernelParams._fields if not re.search(rf"\bp\.{name}\b", source)]
    assert not unread


def test_the_files_measurements_are_given_by_the_caller():
    assert DEFAULT.kernel_params(DEFAULT.model, shape_tolerance=0.05).shape_tolerance == 0.05
    assert "shape_tolerance" not in {f.name for f in FIELDS}  # a measurement of the file, not a setting


def test_kernel_params_have_one_type_per_field_whatever_the_input():
    # an integral float setting from JSON or TOML (min_snr = 8) must not be a new numba signature:
    # that is a fresh compile of the whole engine (about 50 s) in the viewer's try endpoint
    given = kernel_params(DecompositionConfig(min_snr=8, tol=0, generations=30))
    assert [type(v) for v in given] == [type(v) for v in kernel_params(DEFAULT)]
    assert given.min_snr == 8.0 and type(given.min_snr) is float and type(given.generations) is int
    with pytest.raises(TypeError):
        kernel_params(DecompositionConfig(population=60.5))


def test_alpha_is_fixed_under_the_system_and_gaussian_models():
    fixed = {m for m in Model if kernel_params(DEFAULT.replace(model=m)).alpha_fixed}
    assert fixed == {Model.SYSTEM, Model.GAUSSIAN}


@pytest.mark.parametrize("changes, message", [
    ({"population": 4}, "population (NP) must be at least 5: MDE draws 4 distinct partners"),
    ({"generations": -1}, "generations (G) must be at least 0"),
    ({"crossover_rate": 1.5}, "crossover_rate (CR) must lie in [0, 1]"),
    ({"noise_threshold": 0.0}, "noise_threshold must be positive"),
    ({"lm_tolerance": 1.0}, "lm_tolerance must lie in (0, 1)"),
    ({"ga_iterative_r2": 0.0}, "ga_iterative_r2 must lie in (0, 1]"),
    ({"scale_min": 0.5, "scale_max": 0.4}, "0 <= a < b"),
])
def test_a_value_outside_its_interval_is_refused_with_the_interval(changes, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        DEFAULT.replace(**changes)


def test_the_catalogue_says_what_the_kernels_do_for_every_optimizer():
    assert set(OPTIMIZERS) == set(Optimizer)
    assert len({spec.code for spec in OPTIMIZERS.values()}) == len(OPTIMIZERS)
    for optimizer, spec in OPTIMIZERS.items():
        assert spec.description
        assert not spec.search_where_local_fails or (spec.search and spec.local != LOCAL_NONE), optimizer
        assert not spec.deconvolution or spec.own_echoes, optimizer
        params = kernel_params(DEFAULT.replace(optimizer=optimizer))
        assert params.method == spec.code and params.noise_weighted == spec.noise_weighted
    # L-BFGS fits the plain sum of squares, LM the noise-weighted one (docs/method.md)
    assert not OPTIMIZERS[Optimizer.LBFGS].noise_weighted and OPTIMIZERS[Optimizer.LM].noise_weighted


def test_the_file_decides_the_model_under_auto():
    auto = DecompositionConfig(model="auto")
    assert auto.kernel_params(Model.SYSTEM, 0.0).alpha_fixed and not auto.kernel_params(Model.AUTO, 0.0).alpha_fixed
    with pytest.raises(TypeError):
        auto.kernel_params(Model.AUTO, shape_tolerence=0.1)


def test_a_preset_is_one_entry_its_method_and_what_it_says_of_the_pulse():
    paper, fast = PRESETS["paper"], PRESETS["fast"]
    assert set(PRESETS) == {"paper", "fast"}
    published = paper.config()
    assert (published.optimizer, published.model, published.generations, published.tol, published.atol) == (
        Optimizer.MDE, Model.GENERALIZED, 80, 0.0, 0.0)
    assert not published.select_echoes and not published.raw_polish and published.min_amplitude_ratio == 0.2
    assert paper.overrides == {"shape_tolerance": 0.0}  # the paper's constant noise: its model taken as exact
    assert fast.config().optimizer is Optimizer.LM and fast.config().lm_iterations == 20 and fast.overrides == {}
    # what a preset changes is what it names (the paper's atol 0 is the default's too: named, as G is fixed)
    for preset in PRESETS.values():
        assert preset.config().changes().items() <= preset.settings.items()
    assert set(paper.settings) - set(published.changes()) == {"atol"}


def test_an_earlier_run_s_retired_settings_read_at_their_one_value_and_no_other():
    earlier = {**DEFAULT.to_dict(), "de_scale_factor": 0.5, "init_spread": 0.25}
    assert DecompositionConfig.from_dict(earlier) == DEFAULT
    with pytest.raises(ValueError, match="unknown decomposition settings \\['init_spread'\\]"):
        DecompositionConfig.from_dict({**earlier, "init_spread": 0.5})
