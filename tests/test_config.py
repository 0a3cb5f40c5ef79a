"""Task configuration as validated data: conversions, ranges, unknown keywords, the generated keyword docs,
and a fuzz test over every task (random keywords, valid and invalid, and random actions)."""

from __future__ import annotations

import dataclasses
import math
import signal
import types
import typing
from pathlib import Path

import numpy as np
import pytest
from dm_env import specs

from mjdrive import ConfigError, suite
from mjdrive.agents.config import apply_overrides
from mjdrive.config import Config, param, parse_task_kwargs, parse_value
from mjdrive.traffic import TrafficConfig

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass(frozen=True)
class Example(Config):
    rate: float = param(1.0, "a rate", "1/s", gt=0.0, le=10.0)
    count: int = param(2, "a count", ge=0)
    mode: str = param("a", "a mode", choices=("a", "b"))
    pair: tuple[float, float] = param((0.0, 1.0), "a pair", ge=0.0)
    limit: float | None = param(None, "an optional limit", "m", gt=0.0)
    flags: dict[str, int] | None = param(None, "counts by name", ge=0, keys=("x", "y"))
    traffic: TrafficConfig = param(TrafficConfig(), "nested")


def test_values_are_converted_to_the_declared_types():
    config = Example.from_dict({"rate": 2, "count": 3.0, "pair": [1, 2], "flags": {"x": 1.0},
                                "traffic": {"min_gap": 3}})
    assert config.rate == 2.0 and isinstance(config.rate, float)
    assert config.count == 3 and isinstance(config.count, int)
    assert config.pair == (1.0, 2.0) and isinstance(config.pair, tuple)
    assert config.flags == {"x": 1} and isinstance(config.flags["x"], int)
    assert config.traffic.min_gap == 3.0 and config.traffic.max_decel == TrafficConfig().max_decel
    assert dataclasses.replace(config, rate=5.0).rate == 5.0
    with pytest.raises(ConfigError, match=r"rate=20\.0: must be > 0 and <= 10 \[1/s\]"):
        dataclasses.replace(config, rate=20.0)  # replace() validates too


@pytest.mark.parametrize("values, message", [
    ({"rate": 0}, r"rate=0: must be > 0 and <= 10 \[1/s\]"),
    ({"rate": math.inf}, "rate=inf: must be a finite number"),
    ({"rate": True}, "rate=True: must be a number"),
    ({"count": 1.5}, "count=1.5: must be an integer"),
    ({"count": "3"}, "count='3': must be an integer"),
    ({"mode": "c"}, "mode='c': must be one of 'a', 'b'"),
    ({"pair": [1.0]}, "must have 2 elements, got 1"),
    ({"pair": "ab"}, "pair='ab': must be a list"),
    ({"pair": [1.0, -1.0]}, r"element 1 \(-1.0\) must be >= 0"),
    ({"limit": -1}, r"limit=-1: must be > 0 \[m\]"),
    ({"limit": "far"}, "limit='far': must be a number or None"),
    ({"flags": {"z": 1}}, "unknown key 'z'; valid keys: x, y"),
    ({"flags": {"x": -1}}, r"\['x'\]=-1 must be >= 0"),
    ({"traffic": {"min_gp": 1}}, "unknown keyword 'min_gp' \\(did you mean 'min_gap'\\?\\)"),
    ({"traffic": 3}, "must be a mapping of TrafficConfig keywords"),
    ({"rat": 1}, "unknown keyword 'rat' \\(did you mean 'rate'\\?\\); valid keywords: rate, count"),
])
def test_bad_values_name_the_keyword_the_value_and_what_is_allowed(values, message):
    with pytest.raises(ConfigError, match=message):
        Example.from_dict(values)


def test_config_errors_are_value_errors_and_none_stays_none():
    assert issubclass(ConfigError, ValueError)
    assert Example.from_dict({"limit": None}).limit is None
    rows = {row["name"]: row for row in Example.describe()}
    assert rows["rate"]["allowed"] == "> 0 and <= 10" and rows["rate"]["unit"] == "1/s"
    assert rows["mode"]["allowed"] == "one of 'a', 'b'"


def test_docs_task_kwargs_is_generated_from_the_configs():
    """docs/task_kwargs.md is exactly `mjdrive list --kwargs all`: the docs cannot drift from the checks."""
    committed = (ROOT / "docs" / "task_kwargs.md").read_text()
    assert committed == suite.kwargs_reference(), "regenerate: mjdrive list --kwargs all > docs/task_kwargs.md"
    for domain, task in suite.ALL_TASKS:
        config_class, _ = suite.task_config(domain, task)
        for field in dataclasses.fields(config_class):
            assert f"| `{field.name}` |" in committed


def test_every_task_takes_physics_dt_and_checks_the_control_period():
    for domain, task in suite.ALL_TASKS:
        config_class, defaults = suite.task_config(domain, task)
        assert "physics_dt" in {f.name for f in dataclasses.fields(config_class)}
    env = suite.load("waypoints", "straight", {"random": 0, "physics_dt": 0.002})
    assert env.physics.timestep() == 0.002 and env.control_timestep() == pytest.approx(0.1)
    with pytest.raises(ConfigError, match="whole multiple of physics_dt=0.003"):
        suite.load("waypoints", "straight", {"physics_dt": 0.003})
    with pytest.raises(ConfigError, match="pass environment_kwargs as load"):
        suite.load("waypoints", "straight", {"environment_kwargs": {}})


# --- fuzz: random keywords (valid and invalid) and random actions over every task -------------------------

# Valid values of expensive keywords stay small so that the fuzz runs in seconds (their ranges are tested
# above); invalid values still use the whole range.
CHEAP = {"image_size": (16, 64), "warmup": (0.0, 3.0), "frames": (1, 4), "arm_length": (30.0, 80.0),
         "time_limit": (0.5, 30.0), "neighbours": (1, 12), "town_blocks": (1, 2), "road_users": (0, 6)}


def _valid(rng: np.random.Generator, name: str, tp, spec):
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in args if a is not type(None) and a is not np.random.RandomState]
        if type(None) in args and rng.random() < 0.3:
            return None
        return _valid(rng, name, options[rng.integers(len(options))], spec)
    low = spec.ge if spec.ge is not None else spec.gt
    high = spec.le if spec.le is not None else spec.lt
    if name in CHEAP:
        low, high = CHEAP[name]
    if tp is bool:
        return bool(rng.integers(2))
    if tp is str:
        return spec.choices[rng.integers(len(spec.choices))]
    if tp is int:
        low, high = int(low if low is not None else 0), int(high if high is not None else 100)
        return int(rng.integers(low, high + 1))
    if tp is float:
        low = low if low is not None else 0.0
        high = high if high is not None else low + 100.0
        value = float(rng.uniform(low, high))
        return value if spec.gt is None or value > spec.gt else high
    if origin is tuple:
        n = spec.length or (len(args) if args[-1] is not Ellipsis else int(rng.integers(1, 4)))
        element = args[0]
        if spec.choices is None and element is int and n > 1 and args[-1] is Ellipsis:
            return tuple(int(v) for v in rng.choice(np.arange(int(low), int(high) + 1), min(n, int(high - low + 1)),
                                                    replace=False))
        return tuple(_valid(rng, name, element, spec) for _ in range(n))
    if origin is dict:
        keys = list(spec.keys)
        chosen = rng.choice(keys, rng.integers(1, len(keys) + 1), replace=False)
        return {str(k): _valid(rng, name, int, spec) for k in chosen}
    if isinstance(tp, type) and issubclass(tp, Config):
        return {}
    raise AssertionError(f"no generator for {name}: {tp}")


def _invalid(rng: np.random.Generator, name: str, tp, spec):
    bounds = [b for b in (spec.ge, spec.gt, spec.le, spec.lt) if b is not None]
    options = ["text", [1.0, "x"], float("nan"), {"nested": 1}]
    if bounds:
        options += [min(bounds) - 1.0, max(bounds) * 2 + 1.0]
    if spec.choices is not None:
        options.append("no_such_choice")
    return options[rng.integers(len(options))]


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


def test_fuzz_every_task_gives_a_working_env_or_a_config_error():
    rng = np.random.default_rng(20)
    previous = signal.signal(signal.SIGALRM, _alarm)
    built = refused = 0
    try:
        for trial in range(70):
            domain, task = suite.ALL_TASKS[trial % len(suite.ALL_TASKS)]
            config_class, defaults = suite.task_config(domain, task)
            hints = typing.get_type_hints(config_class)
            fields = [f for f in dataclasses.fields(config_class) if f.name != "random"]
            kwargs = {"random": int(rng.integers(2**31))}
            invalid = rng.random() < 0.5
            for k, i in enumerate(rng.choice(len(fields), rng.integers(1, 4), replace=False)):
                field = fields[i]
                spec = field.metadata["spec"]
                make = _invalid if invalid and k == 0 else _valid
                kwargs[field.name] = make(rng, field.name, hints[field.name], spec)
            if invalid and rng.random() < 0.2:
                kwargs["no_such_keyword"] = 1
            signal.alarm(60)
            try:
                env = suite.load(domain, task, kwargs)
            except ConfigError as error:
                assert str(error), kwargs
                refused += 1
                continue
            finally:
                signal.alarm(0)
            assert not invalid, f"{domain}/{task} accepted invalid keywords {kwargs}"
            signal.alarm(60)
            try:
                timestep = env.reset()
                spec = env.action_spec()
                for _ in range(5):
                    if isinstance(spec, specs.DiscreteArray):  # the urban decision actions
                        action = int(rng.integers(spec.num_values))
                    else:
                        action = rng.uniform(spec.minimum - 0.5, spec.maximum + 0.5)  # out-of-range values are clipped
                    timestep = env.step(action)
                    for key, value in timestep.observation.items():
                        assert value.size > 0 and value.shape == env.observation_spec()[key].shape, (key, kwargs)
                    if timestep.last():
                        timestep = env.reset()
            finally:
                signal.alarm(0)
            built += 1
            env.close()
    except _Timeout:
        pytest.fail(f"{domain}/{task} with {kwargs} took over 60 s")
    finally:
        signal.signal(signal.SIGALRM, previous)
    print(f"fuzz: {built} envs built and stepped, {refused} refused")
    assert built >= 5 and refused >= 5, (built, refused)


def test_a_command_line_value_reads_one_way_everywhere():
    """`--task-kwarg` (run, drive, eval, the tools) and train's overrides read VALUE alike: JSON, else YAML's
    else YAML, else the text itself."""
    cases = {"3": 3, "-2": -2, "1.5": 1.5, "1e-4": 1e-4, ".5": 0.5, "true": True, "True": True, "FALSE": False,
             "null": None, "~": None, "": None, "camera": "camera", "roundabout/d120": "roundabout/d120",
             "yes": True, '"a b"': "a b", "'it''s'": "it's", '["depth", "range"]': ["depth", "range"],
             "[depth, range]": ["depth", "range"], "[32,32]": [32, 32], "[]": [], "[a, 'b, c',]": ["a", "b, c"],
             "[1, [2, 3]]": [1, [2, 3]], '{"car": 5}': {"car": 5},
             "{channels: [8, 16], pool: none, flatten: true}": {"channels": [8, 16], "pool": "none", "flatten": True},
             "[1, 2": "[1, 2", "a: b": {"a": "b"}, "{a": "{a"}
    for text, value in cases.items():
        assert parse_value(text) == value and type(parse_value(text)) is type(value), text
    assert parse_task_kwargs(["time_limit=3", "sensors=[depth]", "name=a=b"]) == {
        "time_limit": 3, "sensors": ["depth"], "name": "a=b"}
    for bad in ("time_limit", "=3"):
        with pytest.raises(ValueError, match="expects KEY=VALUE"):
            parse_task_kwargs([bad])
    assert apply_overrides({"task_kwargs": {"a": 1}}, ["task_kwargs.sensors=[depth]", "lr=1e-4"]) == {
        "task_kwargs": {"a": 1, "sensors": ["depth"]}, "lr": 1e-4}
