"""The learning diagnostics: what one step records, the columns a metrics window makes of them, and an
iteration that gathers them without changing what it trains."""

from __future__ import annotations

import csv
import dataclasses
import math
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.envs import MultiTaskEnv
from swat_jax.envs.multi_task import EpisodeStats
from swat_jax.networks import make_actor_critic, network_config, task_set
from swat_jax.plot import DIAGNOSTIC_ROWS, plot_diagnostics
from swat_jax.plot import main as plot_main
from swat_jax.runs.checkpoint import flatten
from swat_jax.runs.metrics import DIAGNOSTICS, MetricsWindow, read_metrics
from swat_jax.td3 import diagnostics
from swat_jax.td3.diagnostics import EpisodeValues
from swat_jax.td3.iteration import IterationConfig, init_train_state, make_train_iteration, seed_keys
from swat_jax.td3.learner import Learner, TD3Config

NETWORK = network_config("swat", width=16, layers=1, feedforward=32)
FEATURES = 19
"""A 2D limb's observation features."""


def _step(values, q, reward, ended, stepping=(True, True), policy_phase=True, policy=None, action=None):
    """One step of 2 seeds, 1 body, 2 copies of 3 limbs (the first, the torso, without a motor)."""
    q = jnp.asarray(q, jnp.float32)
    policy = jnp.zeros((2, 1, 2, 3)) if policy is None else jnp.asarray(policy, jnp.float32)
    action = policy if action is None else jnp.asarray(action, jnp.float32)
    mask = jnp.array([[[False, True, True]]])  # [K, 1, L]
    return diagnostics.step(
        values, q, q + 1.0, policy, action, mask, jnp.asarray(reward, jnp.float32), jnp.asarray(ended),
        jnp.asarray(stepping), jnp.full(2, policy_phase), 0.5,
    )  # fmt: skip


def test_each_episode_is_scored_by_its_first_estimate_and_its_discounted_return():
    """Copy 0 of seed 0 runs an episode of three steps (rewards 4, 2, 8): its estimate is the one at the
    first state (the twins' mean 10.5), its return 4 + 0.5 * 2 + 0.25 * 8 = 7; the next episode starts
    fresh and takes its own first estimate. Seed 1 waits at the last step: it keeps its episode and records
    nothing."""
    values = EpisodeValues.fresh((2, 1, 2))
    ended = [[[False, False]], [[False, False]]]
    values, first = _step(values, [[[10.0, 1.0]], [[3.0, 3.0]]], [[[4.0, 1.0]], [[1.0, 1.0]]], ended)
    values, _ = _step(values, [[[99.0, 99.0]], [[99.0, 99.0]]], [[[2.0, 1.0]], [[1.0, 1.0]]], ended)
    values, last = _step(
        values, [[[77.0, 77.0]], [[77.0, 77.0]]], [[[8.0, 1.0]], [[1.0, 1.0]]],
        [[[True, False]], [[True, True]]], stepping=(True, False),
    )  # fmt: skip
    np.testing.assert_allclose(last.ended_estimate, [[[10.5, 0.0]], [[0.0, 0.0]]])
    np.testing.assert_allclose(last.ended_return, [[[7.0, 0.0]], [[0.0, 0.0]]])
    np.testing.assert_allclose(last.ended, [[[1.0, 0.0]], [[0.0, 0.0]]])
    np.testing.assert_allclose(last.stepped, [[[1.0, 1.0]], [[0.0, 0.0]]])
    np.testing.assert_allclose(first.twin_gap, np.ones((2, 1, 2)))
    np.testing.assert_allclose(values.discount, [[[1.0, 0.125]], [[0.25, 0.25]]], err_msg="reset / held")
    np.testing.assert_allclose(values.discounted, [[[0.0, 1.75]], [[1.5, 1.5]]])
    _, next_episode = _step(values, [[[5.0, 0.0]], [[0.0, 0.0]]], jnp.zeros((2, 1, 2)), [[[True, False]]] * 2)
    np.testing.assert_allclose(next_episode.ended_estimate[0, 0, 0], 5.5, err_msg="a fresh first estimate")


def test_saturation_and_noise_count_the_real_motors_and_the_policy_phase():
    """The torso (no motor) saturates and takes noise that neither measure counts; the noise counts only
    steps of the policy phase."""
    policy = jnp.broadcast_to(jnp.array([1.0, 1.0, 0.2]), (2, 1, 2, 3))
    action = jnp.broadcast_to(jnp.array([0.0, 1.0, 0.5]), (2, 1, 2, 3))
    zeros = jnp.zeros((2, 1, 2))
    no_end = jnp.zeros((2, 1, 2), bool)
    _, acted = _step(EpisodeValues.fresh((2, 1, 2)), zeros, zeros, no_end, policy=policy, action=action)
    np.testing.assert_allclose(acted.saturated, np.full((2, 1, 2), 0.5))
    np.testing.assert_allclose(acted.noise_square, np.full((2, 1, 2), 0.3**2 / 2), rtol=1e-6)
    _, random = _step(
        EpisodeValues.fresh((2, 1, 2)), zeros, zeros, no_end, policy_phase=False, policy=policy, action=action
    )
    np.testing.assert_allclose(random.noise_square, np.zeros((2, 1, 2)))
    np.testing.assert_allclose(random.explored, np.zeros((2, 1, 2)))


def _window_metrics(sums: dict[str, list[float]]) -> dict:
    """One iteration's metrics of 1 seed, 2 bodies, with these diagnostic sums [K] (others 0)."""
    diag = {name: np.asarray([sums.get(name, [0.0, 0.0])], np.float64) for name in DIAGNOSTICS}
    zero = np.zeros((1, 2))
    return {
        "critic_loss": np.zeros((1, 3)),
        "actor_loss": np.zeros((1, 3)),
        "counted_steps": np.zeros(1),
        "stored_steps": np.zeros(1),
        "episodes": EpisodeStats(return_sum=zero, length_sum=zero, count=zero),
        "diagnostics": diag,
    }


def test_a_window_turns_the_sums_into_means_per_body():
    """Two iterations summed: means over the episodes (estimate, return, their difference), over the steps
    (twin gap, saturation), the noise's root mean square over the policy steps, the update shares; NaN where
    a body finished no episode."""
    window = MetricsWindow(1, 2, diagnostics=True)
    first = {"estimate": [30.0, 0.0], "return": [10.0, 0.0], "episodes": [2.0, 0.0], "twin_gap": [4.0, 1.0]}
    first |= {"steps": [8.0, 8.0], "saturated": [2.0, 4.0], "noise_square": [0.08, 0.5]}
    first |= {"policy_steps": [8.0, 8.0], "updates": [3.0, 3.0]}
    window.add(_window_metrics(first))
    window.add(_window_metrics({"estimate": [10.0, 0.0], "episodes": [2.0, 0.0], "updates": [1.0, 3.0]}))
    row = window.rows([0], ["hopper_3.xml", "walker_7_main.xml"])[0]
    assert row["diag/estimate/hopper_3"] == 10.0
    assert row["diag/return/hopper_3"] == 2.5
    assert row["diag/overestimate/hopper_3"] == 7.5
    assert math.isnan(row["diag/estimate/walker_7_main"])
    assert row["diag/twin_gap/walker_7_main"] == 1.0 / 8
    assert row["diag/saturated/hopper_3"] == 0.25
    assert row["diag/noise/hopper_3"] == pytest.approx(0.1)
    assert row["diag/update_share/hopper_3"] == 0.4
    restored = MetricsWindow(1, 2, window.to_json(), diagnostics=True)
    assert restored.rows([0], ["hopper_3.xml", "walker_7_main.xml"])[0] == pytest.approx(row, nan_ok=True)
    assert not any(key.startswith("diag/") for key in MetricsWindow(1, 2).rows([0], ["a", "b"])[0])


@pytest.fixture(scope="module")
def one_hopper():
    """hopper_3 alone, 1 copy on MuJoCo C, random actions throughout (seed 0 falls once in the first 200
    steps, at step 175): a learner and the iteration config."""
    tasks = task_set(["hopper_3"], NETWORK, max_limbs=4)
    actor, critic = make_actor_critic(NETWORK, FEATURES)
    env = MultiTaskEnv(["hopper_3"], copies=1, max_limbs=4, physics="c")
    learner = Learner(actor, critic, TD3Config(batch_size=4))
    config = IterationConfig(chunk=200, updates=2, random_steps=1000, capacity=512, loop="all_tasks")
    return env, tasks.structure, learner, config


@pytest.mark.slow
def test_the_iteration_scores_an_episode_by_the_critics_and_the_rewards_it_logged(one_hopper):
    """The first iteration: the random hopper falls once; its estimate is the initial critics' value of the
    first state and the policy's action there, its return the discounted sum of the rewards the iteration
    logged up to the fall."""
    env, structure, learner, config = one_hopper
    start = init_train_state(env, learner, config, seed_keys(0, 1))
    state, metrics = make_train_iteration(env, structure, learner, config)(start)
    episodes = metrics["episodes"]
    assert int(episodes.count[0, 0]) == 1, "the chunk holds exactly one fall"
    length = int(episodes.length_sum[0, 0])
    reward = np.asarray(metrics["reward"][0, :length, 0, 0], np.float64)
    discounted = np.sum(reward * learner.config.discount ** np.arange(length))
    observation = start.env.observation[0, 0]  # [n, L, F]
    one = jax.tree.map(lambda leaf: leaf[0], structure)
    policy = learner.actor.apply(_seed(start.learner.actor_params), observation, one)
    q1, q2 = learner.body_values(_seed(start.learner.critic_params), observation, policy, one)
    sums = metrics["diagnostics"]
    np.testing.assert_allclose(sums["estimate"][0, 0], (q1[0] + q2[0]) / 2, rtol=1e-5)
    np.testing.assert_allclose(sums["return"][0, 0], discounted, rtol=1e-5)
    assert float(sums["episodes"][0, 0]) == 1.0
    assert float(sums["steps"][0, 0]) == config.chunk
    assert float(sums["policy_steps"][0, 0]) == 0.0, "random actions throughout"
    assert float(sums["updates"][0, 0]) == config.updates
    assert float(state.episode_values.discount[0, 0, 0]) < 1.0, "the next episode has begun"


def _seed(params):
    """Seed 0's parameters of a state with one seed."""
    return jax.tree.map(lambda leaf: leaf[0], params)


def test_the_diagnostics_change_nothing_the_iteration_trains(one_hopper):
    """Two iterations (the second updating) with the diagnostics and without: every array of the state they
    share is equal bit for bit, and so are the losses."""
    env, structure, learner, config = one_hopper
    runs = {}
    for gathered in (True, False):
        with_or_without = dataclasses.replace(config, diagnostics=gathered)
        iteration = jax.jit(make_train_iteration(env, structure, learner, with_or_without))
        state = init_train_state(env, learner, with_or_without, seed_keys(0, 1))
        state, _ = iteration(state)
        state, metrics = iteration(state)
        runs[gathered] = (flatten(state.replace(episode_values=None)), metrics["critic_loss"])
    (with_state, with_loss), (without_state, without_loss) = runs[True], runs[False]
    assert with_state.keys() == without_state.keys()
    assert [key for key in with_state if not np.array_equal(with_state[key], without_state[key])] == []
    np.testing.assert_array_equal(with_loss, without_loss)


def test_the_diagnostics_figure_draws_a_line_per_seed_of_each_column(trained_run, tmp_path, capsys):
    """The tiny run (2 seeds, hopper_3): a row per diagnostic, a line per seed of its metrics.csv values (two
    per seed where the estimate meets the return), the seeds' colours the same in every row. The command
    says once where it wrote the figure."""
    output = tmp_path / "diagnostics.png"
    assert plot_main(["diagnostics", str(trained_run), "-o", str(output)]) == 0
    assert output.stat().st_size > 0
    printed = capsys.readouterr()
    assert (printed.out + printed.err).count(f"wrote {output}") == 1
    figure = plot_diagnostics(trained_run, tmp_path / "again.png")
    rows = read_metrics(trained_run)
    assert len(figure.axes) == len(DIAGNOSTIC_ROWS)
    for axes, (columns, _) in zip(figure.axes, DIAGNOSTIC_ROWS, strict=True):
        lines = axes.get_lines()
        assert len(lines) == 2 * len(columns)
        assert {line.get_color() for line in lines} == {"C0", "C1"}
        for line, (seed, column) in zip(lines, [(s, c) for s in (0, 1) for c in columns], strict=True):
            expected = [
                (row["env_steps"], row[f"{column}/hopper_3"])
                for row in rows
                if row["seed"] == seed and math.isfinite(row[f"{column}/hopper_3"])
            ]
            assert list(zip(*line.get_data(), strict=True)) == expected
    assert figure.axes[0].get_title() == "hopper_3"


def test_the_diagnostics_figure_refuses_a_run_without_them_and_a_body_it_did_not_train(
    trained_run, tmp_path, capsys
):
    output = str(tmp_path / "f.png")
    assert plot_main(["diagnostics", str(trained_run), "-o", output, "--bodies", "walker_7_main"]) == 2
    assert "did not train walker_7_main; its bodies: hopper_3" in capsys.readouterr().err
    older = tmp_path / "older"
    older.mkdir()
    shutil.copy(trained_run / "config.json", older)
    with (trained_run / "metrics.csv").open(newline="") as file:
        table = list(csv.reader(file))
    kept = [index for index, column in enumerate(table[0]) if not column.startswith("diag/")]
    with (older / "metrics.csv").open("w", newline="") as file:
        csv.writer(file).writerows([[row[index] for index in kept] for row in table])
    assert plot_main(["diagnostics", str(older), "-o", output]) == 2
    error = capsys.readouterr().err
    assert "no diag/* columns" in error and "--iteration.no-diagnostics" in error
    assert not (tmp_path / "f.png").exists()
