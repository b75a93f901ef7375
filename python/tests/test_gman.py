"""Tests of the installed `gman` package (run by `python/ci.sh` with the venv's pytest)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import SyncVectorEnv

import gman

REPO = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("GMAN_DATA", REPO.parent / "shared" / "data" / "gman"))
BLOB = REPO / "host-sim" / "models" / "gman-map3-b16-mcu-int8-seed5.gman"
IN_CI = bool(os.environ.get("CI"))


def need_data() -> Path:
    """The GMAN data directory; skipped only outside CI when it is absent."""
    if (DATA / "attributes.json").is_file():
        return DATA
    if IN_CI:
        pytest.fail(f"CI is set but the GMAN data is missing at {DATA}")
    pytest.skip(f"GMAN data not found at {DATA} (set GMAN_DATA); CI never skips this")


def gman_cli() -> str:
    """The `gman` binary of this checkout: GMAN_BIN, else the newer of target/{release,debug}."""
    if os.environ.get("GMAN_BIN"):
        return os.environ["GMAN_BIN"]
    built = [p for p in (REPO / "target/release/gman", REPO / "target/debug/gman") if p.is_file()]
    if built:
        return str(max(built, key=lambda p: p.stat().st_mtime))
    if IN_CI:
        pytest.fail("CI is set but no gman binary was built (cargo build -p gman-host-sim)")
    pytest.skip("no gman binary (cargo build -p gman-host-sim, or set GMAN_BIN)")


def test_imports_the_installed_package():
    assert "site-packages" in gman.__file__, gman.__file__
    assert gman.FEATURE_DIM == 512 and gman.ATTR_DIM == 45 and gman.NUM_ACTIONS == 6
    assert "make_vec_env" in (gman.__doc__ or "")


def test_gymnasium_env_checker_passes():
    env = gymnasium.make("gman/ObjectNav-v0")
    check_env(env.unwrapped)  # render check included: the spec makes it with rgb_array
    check_env(gman.ObjectNavEnv(map=(3, 3), max_steps=20, render_mode="rgb_array"))


def test_registered_vector_entry_point():
    env = gymnasium.make_vec("gman/ObjectNav-v0", num_envs=3, vectorization_mode="vector_entry_point")
    assert isinstance(env, gman.VecEnv) and env.num_envs == 3
    obs, info = env.reset(seed=1)
    assert obs["features"].shape == (3, 512) and obs["features"].dtype == np.float32
    assert env.observation_space.contains(obs)


def _random_actions(n_steps: int, b: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 6, size=(n_steps, b))


@pytest.mark.parametrize("b,steps", [(4, 400), (160, 60)])  # 160: stepped on several threads
def test_vec_env_equals_sync_vector_env_of_single_envs(b, steps):
    vec = gman.make_vec_env(num_envs=b, map=(2, 3), max_steps=30, copy=True)
    sync = SyncVectorEnv([lambda: gman.ObjectNavEnv(map=(2, 3), max_steps=30) for _ in range(b)])
    o1, i1 = vec.reset(seed=7)
    o2, i2 = sync.reset(seed=7)
    acts = _random_actions(steps, b, 0)
    ends = 0
    for t in range(steps):
        for k in o1:
            np.testing.assert_array_equal(o1[k], o2[k], err_msg=f"obs {k} at step {t}")
        for k in ("scene", "target_category", "shortest_path", "episode_seed", "steps"):
            np.testing.assert_array_equal(i1[k], i2[k], err_msg=f"info {k} at step {t}")
        o1, r1, te1, tr1, i1 = vec.step(acts[t])
        o2, r2, te2, tr2, i2 = sync.step(acts[t])
        np.testing.assert_array_equal(r1, r2.astype(np.float32))
        np.testing.assert_array_equal(te1, te2)
        np.testing.assert_array_equal(tr1, tr2)
        ends += int(te1.sum() + tr1.sum())
    assert ends > 10  # several autoresets were compared


def test_next_step_autoreset():
    env = gman.make_vec_env(num_envs=2, max_steps=3)
    env.reset(seed=0)
    done = np.array([5, 0])
    _, r, te, tr, info = env.step(done)
    assert te.tolist() == [True, False] and tr.tolist() == [False, False]
    seed_before = int(info["episode_seed"][0])
    _, r, te, tr, info = env.step(np.array([0, 0]))
    assert info["episode_start"].tolist() == [True, False]
    assert r[0] == 0.0 and not te[0] and not tr[0]
    assert int(info["episode_seed"][0]) != seed_before
    _, r, te, tr, info = env.step(np.array([0, 0]))
    assert tr.tolist() == [False, True]  # slot 1 reached its limit of 3 steps


def _strip(report: dict) -> dict:
    return {k: v for k, v in report.items() if k != "agent"}


def _same_episodes(a: list, b: list) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x == y, (x, y)


def oracle_policy(obs, info):
    return info["oracle_action"]


def test_oracle_sr_100_and_python_loop_equals_rust_evaluator():
    host, host_eps = gman.evaluate("oracle", return_episodes=True)
    assert host["results"]["seen"]["sr"] == 100.0 and host["results"]["unseen"]["sr"] == 100.0
    py, py_eps = gman.evaluate(oracle_policy, num_envs=32, return_episodes=True)
    assert _strip(host) == _strip(py)
    _same_episodes(host_eps, py_eps)  # every episode: steps, return, success, SPL, EPA, DTS


def test_oracle_on_the_data_and_the_cli(tmp_path):
    data = need_data()
    host, host_eps = gman.evaluate("oracle", data=data, episodes=25, return_episodes=True)
    assert host["episodes"] > 0
    assert host["results"]["seen"]["sr"] == 100.0 and host["results"]["unseen"]["sr"] == 100.0
    py, py_eps = gman.evaluate(oracle_policy, data=data, episodes=25, num_envs=16, return_episodes=True)
    assert _strip(host) == _strip(py)
    _same_episodes(host_eps, py_eps)
    out = tmp_path / "oracle.json"
    subprocess.run(
        [gman_cli(), "eval", "--data", str(data), "--agent", "oracle", "--episodes", "25",
         "--quiet", "--json", str(out)],
        check=True, stdout=subprocess.DEVNULL,
    )
    assert _strip(json.loads(out.read_text())) == _strip(host)


def _navigator_policy(blob: bytes, b: int):
    navs = [gman.Navigator.from_blob(blob) for _ in range(b)]
    acts = np.zeros(b, np.int64)

    def policy(obs, info):
        for i in range(b):
            if info["ended"][i]:
                continue  # this slot resets at this step; its action is ignored
            if info["episode_start"][i]:
                navs[i].reset(obs["target"][i], int(info["episode_seed"][i]))
            acts[i], _, _, _ = navs[i].step(obs["features"][i], map=obs["map"][i])
        return acts

    return policy


def test_shipped_blob_gives_gman_evals_numbers(tmp_path):
    data = need_data()
    assert BLOB.is_file(), BLOB
    blob = BLOB.read_bytes()
    n = 6
    host, host_eps = gman.evaluate(str(BLOB), data=data, episodes=n, return_episodes=True)
    from_bytes = gman.evaluate(blob, data=data, episodes=n)
    assert _strip(from_bytes) == _strip(host)
    # The same episodes driven from Python by gman.Navigator, one per slot.
    py, py_eps = gman.evaluate(
        _navigator_policy(blob, 8), data=data, episodes=n, num_envs=8, map=(3, 3),
        return_episodes=True,
    )
    _same_episodes(host_eps, py_eps)
    assert _strip(py) == _strip(host)
    out = tmp_path / "blob.json"
    subprocess.run(
        [gman_cli(), "eval", "--data", str(data), "--agent", str(BLOB), "--episodes", str(n),
         "--quiet", "--json", str(out)],
        check=True, stdout=subprocess.DEVNULL,
    )
    assert _strip(json.loads(out.read_text())) == _strip(host)


def test_val_split_iterates_the_official_episodes_in_order():
    env = gman.make_vec_env(split="val", num_envs=3)
    _, info = env.reset()
    assert info["episode_index"].tolist() == [0, 1, 2]
    _, _, _, _, info = env.step(np.full(3, 5))
    _, _, _, _, info = env.step(np.zeros(3, np.int64))
    assert info["episode_index"].tolist() == [3, 4, 5]
    assert env.completed_episodes == 3


def test_navigator_step_and_adapt():
    nav = gman.Navigator.from_file(BLOB)
    assert nav.method == "gman" and nav.map_shape == (3, 3)
    env = gman.make_vec_env(num_envs=1, map=(3, 3))
    obs, info = env.reset(seed=2)
    nav.reset(obs["target"][0], 11)
    for _ in range(5):
        a, p, v, adapted = nav.step(obs["features"][0], map=obs["map"][0])
        assert 0 <= a < 6 and p.shape == (6,) and abs(float(p.sum()) - 1.0) < 1e-5
        assert np.isfinite(v)
        obs, *_ = env.step(np.array([a]))
    assert nav.buffered == 5
    assert nav.adapt() is True and nav.buffered == 0


def test_navigator_settings_match_gman_inspect():
    """Every setting the blob records, by key, as `gman inspect` prints them."""
    printed = subprocess.run(
        [gman_cli(), "inspect", str(BLOB)], capture_output=True, text=True, check=True
    ).stdout
    line = next(l for l in printed.splitlines() if l.startswith("settings by key: "))
    want = dict(kv.split("=", 1) for kv in line[len("settings by key: "):].split())
    got = gman.Navigator.from_file(BLOB).settings
    assert list(got) == list(want)
    for key, value in got.items():
        w = want[key]
        if value is None:
            assert w.startswith("("), (key, w)
        elif isinstance(value, bool):
            assert w == str(value).lower(), (key, w)
        elif isinstance(value, float):
            assert float(w) == pytest.approx(value, rel=1e-6), (key, w)
        else:
            assert w == str(value), (key, w)


def test_bad_inputs_raise_clear_exceptions():
    env = gman.make_vec_env(num_envs=2)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2, np.int64))
    env.reset(seed=0)
    with pytest.raises(TypeError, match="integers"):
        env.step(np.zeros(2, np.float32))
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step(np.zeros(3, np.int64))
    with pytest.raises(ValueError, match=r"actions\[1\] = 6"):
        env.step(np.array([0, 6]))
    with pytest.raises(ValueError, match=r"actions\[0\] = -1"):
        env.step(np.array([-1, 0]))
    with pytest.raises(ValueError, match="split"):
        gman.make_vec_env(split="validation")
    with pytest.raises(ValueError, match="reward"):
        gman.make_vec_env(reward="dense")
    with pytest.raises(ValueError, match="num_envs"):
        gman.make_vec_env(num_envs=0)
    with pytest.raises(FileNotFoundError, match="no/such/dir"):
        gman.make_vec_env(data="/no/such/dir")
    with pytest.raises(FileNotFoundError, match="no such model file"):
        gman.evaluate("/no/such/model.gman")
    with pytest.raises(TypeError, match="policy"):
        gman.evaluate(42)

    blob = BLOB.read_bytes()
    nav = gman.Navigator.from_blob(blob)
    obs = np.full(512, 0.5, np.float32)
    with pytest.raises(ValueError, match="reset"):
        nav.step(obs, map=np.zeros((9, 512), np.float32))  # before reset
    nav.reset(np.zeros(45, np.float32), 0)
    with pytest.raises(ValueError, match="obs must have 512"):
        nav.step(np.zeros(100, np.float32), map=np.zeros((9, 512), np.float32))
    with pytest.raises(TypeError, match="obs must be a float array"):
        nav.step(np.zeros(512, np.int32), map=np.zeros((9, 512), np.float32))
    with pytest.raises(ValueError, match="spatial map"):
        nav.step(obs)
    with pytest.raises(ValueError, match="map must have 4608"):
        nav.step(obs, map=np.zeros((3, 512), np.float32))
    bad = obs.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="(?i)finite"):
        nav.step(bad, map=np.zeros((9, 512), np.float32))
    with pytest.raises(ValueError, match="attr must have 45"):
        nav.reset(np.zeros(44, np.float32), 0)
    with pytest.raises(ValueError, match="(?i)finite"):
        nav.reset(np.full(45, np.inf, np.float32), 0)
    with pytest.raises(TypeError, match="bytes"):
        gman.Navigator.from_blob("not bytes")
    with pytest.raises(ValueError, match="blob"):
        gman.Navigator.from_blob(blob[: len(blob) // 2])
    corrupt = bytearray(blob)
    corrupt[len(corrupt) // 2] ^= 0xFF
    with pytest.raises(ValueError, match="blob"):
        gman.Navigator.from_blob(bytes(corrupt))
    with pytest.raises(ValueError, match="blob"):
        gman.evaluate(bytes(corrupt), episodes=1)


def test_the_docs_examples_run_as_written(capsys):
    text = (REPO / "docs" / "python.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 2, "docs/python.md lost its python examples"
    cwd = os.getcwd()
    os.chdir(REPO)
    try:
        for i, block in enumerate(blocks):
            exec(compile(block, f"docs/python.md block {i}", "exec"), {})
    finally:
        os.chdir(cwd)
    out = capsys.readouterr().out
    assert "100.0" in out  # the ten lines' oracle
    assert out.rstrip().endswith("True"), out  # the per-environment navigators equal gman eval


def test_domain_shift_one_is_the_default_and_other_levels_change_what_the_agent_sees():
    def first_obs(**kw):
        env = gman.make_vec_env(num_envs=2, seed=3, copy=True, **kw)
        obs, _ = env.reset()
        env.close()
        return obs["features"]

    base = first_obs()
    assert np.array_equal(base, first_obs(domain_shift=1.0))
    assert np.array_equal(base, first_obs(domain_shift=1))
    assert not np.array_equal(base, first_obs(domain_shift=0.0))
    for bad, kind in [(-0.5, ValueError), (3.5, ValueError), (float("nan"), ValueError), ("1", TypeError), (True, TypeError)]:
        with pytest.raises(kind, match="domain_shift"):
            gman.make_vec_env(domain_shift=bad)
    with pytest.raises(ValueError, match="domain_shift"):
        gman.evaluate("random", split="val", domain_shift=4.0)
