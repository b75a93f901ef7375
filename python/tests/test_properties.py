"""Property test of the package's public surface (`hypothesis`).

For every public function and parameter, generated values (integers at and beyond every
bound, floats, NaN, None, strings, bytes, numpy scalars and arrays of every dtype, tuples of
the wrong length) either succeed or raise ``ValueError`` / ``TypeError`` /
``FileNotFoundError`` whose message names the parameter. Nothing may abort the interpreter,
surface a ``PanicException`` (a ``BaseException``) or change an environment or a navigator
when a call is refused. Calls that size an allocation (``num_envs``, ``map``) or build a world
(``world_seed``) run in a subprocess capped in memory with ``resource.setrlimit``.
"""

from __future__ import annotations

import base64
import math
import os
import pickle
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable, Dict

import hypothesis.extra.numpy as hnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import gman
from gman import _args

REPO = Path(__file__).resolve().parents[2]
BLOB = REPO / "host-sim" / "models" / "gman-map3-b16-mcu-int8-seed5.gman"
ALLOWED = (ValueError, TypeError, FileNotFoundError)
# Examples per parameter: in-process calls, and calls in a capped subprocess (each ~0.5 s).
IN_PROCESS = settings(
    max_examples=60, deadline=None, derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
SUBPROCESS = settings(
    max_examples=12, deadline=None, derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
MEMORY_CAP = 4 << 30  # bytes of address space for a subprocess call

BOUNDS = [
    -(2**64), -(2**63) - 1, -(2**63), -(2**31) - 1, -1, 0, 1, 2, 3, 5, 6, 7, 8, 16, 17,
    2**16, 2**16 + 1, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**40, 2**63 - 1, 2**63,
    2**64 - 1, 2**64, 2**70,
]
DTYPES = [np.dtype(c) for c in "?bBhHiIlLqQefdgFDUSO"] + [np.dtype("M8[s]"), np.dtype("m8[s]")]


def _numpy_scalar(dtype: np.dtype) -> st.SearchStrategy:
    return hnp.arrays(dtype, ()).map(lambda a: a[()])


def hostile() -> st.SearchStrategy:
    """Any value a caller might pass where one argument is expected."""
    small = st.one_of(st.integers(-3, 20), st.floats(allow_nan=True), st.none())
    return st.one_of(
        st.none(),
        st.booleans(),
        st.sampled_from(BOUNDS),
        st.integers(),
        st.floats(allow_nan=True, allow_infinity=True),
        st.sampled_from([3.5, 4.0, -0.0, 1e300, float("nan"), float("-inf")]),
        st.text(max_size=4),
        st.binary(max_size=4),
        st.sampled_from(DTYPES).flatmap(_numpy_scalar),
        hnp.arrays(
            st.sampled_from(DTYPES),
            hnp.array_shapes(min_dims=0, max_dims=2, min_side=0, max_side=3),
        ),
        st.lists(small, max_size=3).map(tuple),
        st.lists(small, max_size=3),
        st.dictionaries(st.text(max_size=2), small, max_size=2),
        st.just(object()),
    )


def names_the_parameter(e: BaseException, name: str, value: Any) -> bool:
    msg = str(e)
    if name in msg:
        return True
    # A missing file may be named by its path instead.
    return isinstance(e, FileNotFoundError) and isinstance(value, str) and value in msg


def check_outcome(call: Callable[[], Any], name: str, value: Any) -> bool:
    """Runs `call`; True if it succeeded, False if refused as the contract says."""
    try:
        call()
        return True
    except ALLOWED as e:
        assert names_the_parameter(e, name, value), f"{name}={value!r}: {type(e).__name__}: {e}"
        return False
    except BaseException as e:  # noqa: BLE001 - a PanicException is a BaseException
        raise AssertionError(f"{name}={value!r} raised {type(e).__name__}: {e}") from e


# --------------------------------------------------------------------------------------------
# make_vec_env / evaluate parameters that allocate nothing large: in process.
# --------------------------------------------------------------------------------------------


def _vec(**kw):
    env = gman.make_vec_env(**kw)
    try:
        env.reset()
        env.step(np.zeros(env.num_envs, np.int64))
    finally:
        env.close()


@pytest.mark.parametrize(
    "name", ["data", "split", "seed", "max_steps", "reward", "episodes", "oracle", "copy", "render_mode"]
)
def test_make_vec_env_parameters(name):
    base = {"split": "val"} if name == "episodes" else {}

    @IN_PROCESS
    @given(hostile())
    def prop(v):
        check_outcome(lambda: _vec(**{**base, name: v}), name, v)

    prop()


@pytest.mark.parametrize(
    "cls,name",
    [("VecEnv", "max_episode_steps"), ("ObjectNavEnv", "num_envs"), ("ObjectNavEnv", "copy")],
)
def test_class_only_parameters(cls, name):
    @IN_PROCESS
    @given(hostile())
    def prop(v):
        def call():
            env = getattr(gman, cls)(**{name: v})
            env.reset(seed=0)
            env.close()

        check_outcome(call, name, v)

    prop()


def oracle_policy(obs, info):
    return info["oracle_action"]


@pytest.mark.parametrize(
    "name", ["policy", "data", "split", "episodes", "max_steps", "reward", "seed", "agent_name", "return_episodes"]
)
def test_evaluate_parameters(name):
    base: Dict[str, Any] = {"episodes": 1}
    base["policy"] = "random" if name == "seed" else "oracle"

    @IN_PROCESS
    @given(hostile())
    def prop(v):
        kw = {**base, name: v}
        policy = kw.pop("policy")
        check_outcome(lambda: gman.evaluate(policy, **kw), name, v)

    prop()


# --------------------------------------------------------------------------------------------
# Sizes and worlds: each call in a subprocess with a memory cap.
# --------------------------------------------------------------------------------------------

_WORKER = r"""
import base64, pickle, resource, sys
cap = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
import numpy as np, gman
fn, kw = pickle.loads(base64.b64decode(sys.stdin.read()))
def oracle_policy(obs, info):
    return info["oracle_action"]
try:
    if fn == "make_vec_env":
        env = gman.make_vec_env(**kw)
        env.reset()
        env.step(np.zeros(env.num_envs, np.int64))
        env.close()
    else:
        policy = kw.pop("policy")
        gman.evaluate(oracle_policy if policy == "callable" else policy, **kw)
    print("OK")
except BaseException as e:
    print("EXC", type(e).__name__, str(e).replace("\n", " "))
"""


def in_subprocess(fn: str, kw: Dict[str, Any]) -> str:
    payload = base64.b64encode(pickle.dumps((fn, kw))).decode()
    p = subprocess.run(
        [sys.executable, "-c", _WORKER, str(MEMORY_CAP)],
        input=payload, capture_output=True, text=True, timeout=120,
    )
    assert p.returncode == 0, f"{fn}({kw!r}) exited with {p.returncode}: {p.stderr[-2000:]}"
    lines = [l for l in p.stdout.splitlines() if l.startswith(("OK", "EXC"))]
    assert lines, f"{fn}({kw!r}): no outcome; stderr: {p.stderr[-2000:]}"
    return lines[-1]


def check_subprocess(fn: str, kw: Dict[str, Any], name: str, value: Any) -> None:
    out = in_subprocess(fn, kw)
    if out == "OK":
        return
    _, kind, msg = (out.split(" ", 2) + [""])[:3]
    # A clean MemoryError is acceptable under the cap; an abort or a panic is not.
    assert kind in ("ValueError", "TypeError", "FileNotFoundError", "MemoryError"), (name, value, out)
    assert name in msg, f"{name}={value!r}: {out}"


def picklable(v: Any) -> bool:
    try:
        pickle.loads(pickle.dumps(v))
        return True
    except Exception:
        return False


def size_values() -> st.SearchStrategy:
    return st.one_of(
        st.sampled_from(BOUNDS),
        st.integers(),
        st.sampled_from([3.5, 4.0, float("nan"), None, "8", (8, 8), (3.5, 3), (4.0, 3)]),
        st.tuples(st.sampled_from(BOUNDS), st.sampled_from(BOUNDS)),
        st.tuples(st.integers(-2, 20), st.integers(-2, 20)),
        st.lists(st.integers(0, 9), max_size=3).map(tuple),
        hostile(),
    ).filter(picklable)


@pytest.mark.parametrize(
    "fn,name,base",
    [
        ("make_vec_env", "num_envs", {}),
        ("make_vec_env", "map", {}),
        ("make_vec_env", "world_seed", {}),
        ("evaluate", "num_envs", {"policy": "callable", "episodes": 1}),
        ("evaluate", "map", {"policy": "callable", "episodes": 1}),
    ],
)
def test_sizes_in_a_capped_subprocess(fn, name, base):
    @SUBPROCESS
    @given(size_values())
    def prop(v):
        check_subprocess(fn, {**base, name: v}, name, v)

    prop()


def test_the_absurd_sizes_of_the_reliability_sweep():
    """The rows of the sweep that aborted or overflowed, each in a capped subprocess."""
    for kw, name in [
        ({"num_envs": 2**40}, "num_envs"),
        ({"num_envs": 2**16, "map": (16, 16)}, "num_envs"),
        ({"map": (2**40, 2**40)}, "map"),
        ({"map": (2**33, 1)}, "map"),
    ]:
        out = in_subprocess("make_vec_env", kw)
        assert out.startswith("EXC ValueError") and name in out, (kw, out)


# --------------------------------------------------------------------------------------------
# Environments and navigators: a refused call changes nothing.
# --------------------------------------------------------------------------------------------


def _snapshot(obs, info):
    return {k: np.array(v, copy=True) for k, v in {**obs, **info}.items()}


def _same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@IN_PROCESS
@given(hostile())
def test_vec_env_step_refused_changes_nothing(actions):
    env = gman.make_vec_env(num_envs=2, map=(2, 2), oracle=True)
    twin = gman.make_vec_env(num_envs=2, map=(2, 2), oracle=True)
    obs, info = env.reset(seed=3)
    twin.reset(seed=3)
    before = _snapshot(obs, info)
    if check_outcome(lambda: env.step(actions), "actions", actions):
        return
    _same(before, _snapshot(env._observation(), env._info()))
    for a in ([0, 1], [2, 5], [0, 0]):
        o1, r1, *_ = env.step(np.array(a))
        o2, r2, *_ = twin.step(np.array(a))
        _same(_snapshot(o1, {}), _snapshot(o2, {}))
        np.testing.assert_array_equal(r1, r2)


@IN_PROCESS
@given(hostile(), st.sampled_from(["step", "reset_seed", "reset_options"]))
def test_single_env_refused_call_changes_nothing(value, call):
    env = gman.ObjectNavEnv(max_steps=30)
    twin = gman.ObjectNavEnv(max_steps=30)
    env.reset(seed=4)
    twin.reset(seed=4)
    if call == "step":
        ok = check_outcome(lambda: env.step(value), "action", value)
    elif call == "reset_seed":
        ok = check_outcome(lambda: env.reset(seed=value), "seed", value)
    else:
        ok = check_outcome(lambda: env.reset(options=value), "options", value)
    if ok:
        return
    for a in (0, 1, 0, 2):
        o1, r1, *_ = env.step(a)
        o2, r2, *_ = twin.step(a)
        _same(o1, o2)
        assert r1 == r2


def _navigator_pair():
    blob = BLOB.read_bytes()
    navs = gman.Navigator.from_blob(blob), gman.Navigator.from_blob(blob)
    attr = np.linspace(0, 1, 45, dtype=np.float32)
    for n in navs:
        n.reset(attr, 9)
    return navs


def _same_future(nav, twin, steps=3):
    rng = np.random.default_rng(0)
    for _ in range(steps):
        obs = rng.random(512, dtype=np.float32)
        m = rng.random(9 * 512, dtype=np.float32)
        a1, p1, v1, d1 = nav.step(obs, map=m)
        a2, p2, v2, d2 = twin.step(obs, map=m)
        assert (a1, v1, d1) == (a2, v2, d2)
        np.testing.assert_array_equal(p1, p2)


@IN_PROCESS
@given(hostile(), st.sampled_from(["obs", "map", "ps", "attr", "seed"]))
def test_navigator_refused_call_changes_nothing(value, name):
    nav, twin = _navigator_pair()
    good_obs = np.full(512, 0.5, np.float32)
    good_map = np.full(9 * 512, 0.5, np.float32)
    if name == "obs":
        call = lambda: nav.step(value, map=good_map)  # noqa: E731
    elif name == "map":
        call = lambda: nav.step(good_obs, map=value)  # noqa: E731
    elif name == "ps":
        call = lambda: nav.step(good_obs, map=good_map, ps=value)  # noqa: E731
    elif name == "attr":
        call = lambda: nav.reset(value, 9)  # noqa: E731
    else:
        call = lambda: nav.reset(np.linspace(0, 1, 45, dtype=np.float32), value)  # noqa: E731
    if check_outcome(call, name, value):
        return
    _same_future(nav, twin)


@IN_PROCESS
@given(hostile())
def test_navigator_constructors(value):
    check_outcome(lambda: gman.Navigator.from_blob(value), "blob", value)
    check_outcome(lambda: gman.Navigator.from_file(value), "path", value)


@IN_PROCESS
@given(hostile())
def test_report_agent(agent):
    env = gman.make_vec_env(split="val", num_envs=4, episodes=1, oracle=True)
    obs, info = env.reset()
    while env.completed_episodes < env.num_episodes:
        obs, _, _, _, info = env.step(info["oracle_action"])
    if check_outcome(lambda: env.report(agent), "agent", agent):
        assert env.report(agent)["agent"] == agent


def test_the_table_of_parameters_is_in_the_docs():
    text = (REPO / "docs" / "python.md").read_text()
    for name in _args.PARAMS:
        assert f"| `{name}` |" in text, f"docs/python.md's parameter table lacks {name}"


def test_integer_rule():
    assert _args.integer("x", 4.0, 0, 9) == 4 and _args.integer("x", np.int8(4), 0, 9) == 4
    for bad, kind in [(3.5, ValueError), (math.nan, ValueError), (True, TypeError), ("4", TypeError), (10, ValueError)]:
        with pytest.raises(kind, match="x"):
            _args.integer("x", bad, 0, 9)
