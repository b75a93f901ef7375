"""The package's boundary: every argument checked with a message naming it, no argument
silently ignored, a closed environment says so, panics never cross, render and the
registration's extras (version, spec, rgb_array)."""

from __future__ import annotations

import importlib.metadata
import os
import re
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import gman

REPO = Path(__file__).resolve().parents[2]
BLOB = REPO / "host-sim" / "models" / "gman-map3-b16-mcu-int8-seed5.gman"


# The rows of the sweep's table: each raises an exception naming its parameter.
@pytest.mark.parametrize(
    "kw,name",
    [
        ({"world_seed": -1}, "world_seed"),
        ({"world_seed": 2**70}, "world_seed"),
        ({"max_steps": 2**40}, "max_steps"),
        ({"max_steps": (200, -1)}, "max_steps"),
        ({"split": "val", "episodes": -1}, "episodes"),
        ({"map": (3.5, 3)}, "map"),
        ({"map": (17, 3)}, "map"),
        ({"map": (0, 3)}, "map"),
        ({"map": (3, 3, 3)}, "map"),
        ({"num_envs": 2**40}, "num_envs"),
        ({"num_envs": 2.5}, "num_envs"),
        ({"num_envs": True}, "num_envs"),
        ({"oracle": "yes"}, "oracle"),
        ({"copy": 1}, "copy"),
        ({"split": None}, "split"),
        ({"reward": 3}, "reward"),
        ({"data": b"/tmp"}, "data"),
        ({"render_mode": "human"}, "render_mode"),
    ],
)
def test_make_vec_env_refusals_name_the_parameter(kw, name):
    with pytest.raises((ValueError, TypeError), match=re.escape(name)):
        gman.make_vec_env(**kw)


def test_seed_beyond_u64_names_the_seed():
    with pytest.raises(ValueError, match="seed"):
        gman.make_vec_env(seed=2**64)
    env = gman.make_vec_env()
    with pytest.raises(ValueError, match="seed"):
        env.reset(seed=2**64)
    with pytest.raises(ValueError, match="seed"):
        env.reset(seed=-1)
    env.reset(seed=2**64 - 1)  # the largest u64 is a seed


def test_integer_valued_floats_are_accepted_fractions_refused():
    env = gman.make_vec_env(num_envs=2.0, map=(4.0, np.int16(3)), max_steps=np.float32(30))
    assert env.num_envs == 2 and env.single_observation_space["map"].shape == (12, 512)
    with pytest.raises(ValueError, match=r"map must be an integer, got 3\.5"):
        gman.make_vec_env(map=(3.5, 3))


def test_evaluate_refusals_name_the_parameter():
    for kw, name in [
        ({"episodes": -1}, "episodes"),
        ({"episodes": 0}, "episodes"),
        ({"seed": 2**64}, "seed"),
        ({"world_seed": -1}, "world_seed"),
        ({"split": "train"}, "split"),
        ({"return_episodes": "yes"}, "return_episodes"),
        ({"agent_name": 7}, "agent_name"),
    ]:
        with pytest.raises((ValueError, TypeError), match=name):
            gman.evaluate("random", **kw)


def test_options_that_do_not_apply_are_refused_not_ignored():
    with pytest.raises(ValueError, match="num_envs.*callable"):
        gman.evaluate("oracle", num_envs=4, episodes=1)
    with pytest.raises(ValueError, match="seed.*random"):
        gman.evaluate("oracle", seed=3, episodes=1)
    with pytest.raises(ValueError, match="map.*takes no map"):
        gman.evaluate("random", map=(3, 3), episodes=1)
    with pytest.raises(ValueError, match="seed"):
        gman.evaluate(lambda obs, info: info["oracle_action"], seed=1, episodes=1)
    blob = BLOB.read_bytes()
    with pytest.raises(ValueError, match="num_envs"):
        gman.evaluate(blob, num_envs=8, episodes=1)
    with pytest.raises(ValueError, match="seed"):
        gman.evaluate(str(BLOB), seed=1, episodes=1)


def test_a_model_refuses_a_contradicting_map_and_accepts_its_own():
    blob = BLOB.read_bytes()  # a 3 x 3 map model
    for policy in (blob, str(BLOB)):
        with pytest.raises(ValueError, match=r"map = \(5, 5\) contradicts the model"):
            gman.evaluate(policy, map=(5, 5), episodes=1)
        a = gman.evaluate(policy, map=(3, 3), episodes=1)
        b = gman.evaluate(policy, episodes=1)
        assert {k: v for k, v in a.items() if k != "agent"} == {k: v for k, v in b.items() if k != "agent"}


def test_a_closed_environment_says_so():
    env = gman.make_vec_env(num_envs=2)
    env.reset(seed=0)
    env.close()
    env.close()  # twice is fine
    for call in (
        lambda: env.step(np.zeros(2, np.int64)),
        lambda: env.reset(),
        lambda: env.report(),
        lambda: env.scene_names(),
        lambda: env.category_names(),
        lambda: env.num_episodes,
        lambda: env.completed_episodes,
        lambda: env.render(),
    ):
        with pytest.raises(RuntimeError, match="the environment is closed") as e:
            call()
        assert isinstance(e.value, gymnasium.error.ClosedEnvironmentError)
    single = gman.ObjectNavEnv()
    single.reset(seed=0)
    single.close()
    single.close()
    for call in (lambda: single.step(0), lambda: single.reset(), lambda: single.render()):
        with pytest.raises(gman.ClosedEnvironmentError, match="the environment is closed"):
            call()


def test_a_panic_surfaces_as_a_runtime_error():
    with pytest.raises(RuntimeError, match="internal error in gman.*panic raised on purpose"):
        gman._gman._panic_for_tests()


def test_action_messages_agree_on_the_range():
    env = gman.make_vec_env(num_envs=1)
    env.reset(seed=0)
    msgs = []
    for bad in (np.array([6]), np.array([1.0])):
        with pytest.raises((ValueError, TypeError)) as e:
            env.step(bad)
        msgs.append(str(e.value))
    assert all("0..=5" in m for m in msgs), msgs
    assert not any("0..6" in m for m in msgs), msgs
    with pytest.raises(ValueError, match=r"actions\[0\] = 18446744073709551615"):
        env.step(np.array([2**64 - 1], np.uint64))  # not wrapped to -1


def test_version_and_spec():
    assert gman.__version__ == importlib.metadata.version("gman")
    spec = gymnasium.spec("gman/ObjectNav-v0")
    assert spec.max_episode_steps == 200
    env = gymnasium.make("gman/ObjectNav-v0")
    assert env.spec.max_episode_steps == 200
    # gymnasium's TimeLimit follows max_episode_steps when it is given with a longer max_steps.
    long = gymnasium.make("gman/ObjectNav-v0", max_steps=500, max_episode_steps=500)
    assert long.spec.max_episode_steps == 500
    long.reset(seed=0)


def test_render_rgb_array():
    env = gymnasium.make("gman/ObjectNav-v0", render_mode="rgb_array")
    check_env(env.unwrapped)  # the render check included
    env.reset(seed=1)
    first = env.render()
    assert first.dtype == np.uint8 and first.ndim == 3 and first.shape[2] == 3
    assert first.shape[0] > 100 and first.shape[1] > 100
    for a in (1, 0, 0):
        env.step(a)
    frame = env.render()
    assert frame.shape == first.shape  # one scene, one size
    assert not np.array_equal(frame, first)  # the path moved
    assert gman.ObjectNavEnv().render() is None  # no render mode: nothing
    vec = gman.make_vec_env(num_envs=3, render_mode="rgb_array")
    vec.reset(seed=2)
    frames = vec.render()
    assert len(frames) == 3 and all(f.dtype == np.uint8 and f.shape[2] == 3 for f in frames)


def test_record_video_writes_a_file(tmp_path):
    if os.environ.get("CI"):
        import moviepy  # noqa: F401  (python/ci.sh installs it: CI never skips this)
    else:
        pytest.importorskip("moviepy", reason="gymnasium's RecordVideo needs moviepy")
    from gymnasium.wrappers import RecordVideo

    env = RecordVideo(
        gymnasium.make("gman/ObjectNav-v0", render_mode="rgb_array", oracle=True),
        str(tmp_path), episode_trigger=lambda i: True, disable_logger=True,
    )
    obs, info = env.reset(seed=0)
    done = False
    while not done:
        obs, r, te, tr, info = env.step(info["oracle_action"])
        done = te or tr
    env.close()
    assert list(tmp_path.glob("*.mp4")), os.listdir(tmp_path)


def test_a_step_refused_as_numerical_changes_nothing():
    blob = BLOB.read_bytes()
    nav, twin = gman.Navigator.from_blob(blob), gman.Navigator.from_blob(blob)
    attr = np.linspace(0, 1, 45, dtype=np.float32)
    nav.reset(attr, 5)
    twin.reset(attr, 5)
    rng = np.random.default_rng(1)
    m = np.full(9 * 512, 0.5, np.float32)
    bad = np.full(512, 0.5, np.float32)
    bad[7] = 3e38  # finite, but overflows inside the step
    with pytest.raises(ValueError):
        nav.step(bad, map=m)
    for _ in range(30):
        obs = rng.random(512, dtype=np.float32)
        a1, p1, v1, d1 = nav.step(obs, map=m)
        a2, p2, v2, d2 = twin.step(obs, map=m)
        np.testing.assert_array_equal(p1, p2)
        assert (a1, v1, d1) == (a2, v2, d2)
