"""The trainer: interface, masking, DIAL gradients, export, determinism, learning."""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from analysis.baselines import random_policy
from analysis.runs import load_map
from models import AgentDQN, DuelingDQN, PairedQNetworks
from multi_agent_env import MultiAgentEnv
from rollout import evaluate_policy
from settings import TrainConfig, field_help

from tests.conftest import load_problem_module

train = load_problem_module("problem2", "train")  # problem1 has a train.py too
build_parser, parse_config = train.build_parser, train.parse_config

TINY = [
    "--total_steps",
    "1536",
    "--num_envs",
    "16",
    "--learning_starts",
    "512",
    "--batch_size",
    "32",
    "--eval_interval",
    "512",
    "--eval_episodes",
    "16",
    "--final_eval_episodes",
    "32",
    "--buffer_size",
    "4096",
    "--target_update",
    "20",
]


def tiny_config(*extra: str) -> TrainConfig:
    return parse_config([*TINY, *extra])


def collect(trainer: train.MultiAgentTrainer, steps: int) -> None:
    """Play ``steps`` vector steps with the trainer's ε and store them, without learning
    (the first three steps of ``train()``'s loop)."""
    rollout = trainer.rollout
    for _ in range(steps):
        actions, messages = trainer.act(rollout.obs, trainer.epsilon, trainer.rng, True)
        next_obs, rewards, terminated, truncated, info = rollout.env.step(actions, messages)
        trainer.store(rollout, actions, messages, rewards, info["final_obs"], terminated, truncated)
        rollout.advance(next_obs, rewards, terminated | truncated)


def filled_trainer(mode: str, *extra: str) -> train.MultiAgentTrainer:
    """A trainer whose buffer holds some experience (no updates yet)."""
    cfg = tiny_config(
        "--mode", mode, "--learning_starts", "100000000", "--total_steps", "1000000000", *extra
    )
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    collect(trainer, 20)
    return trainer


def jit_load(path: Path) -> torch.jit.ScriptModule:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return torch.jit.load(str(path))


# ---------------------------------------------------------------------- networks and masks
@pytest.mark.parametrize("dueling", [False, True])
def test_paired_networks_match_standalone_agents(dueling: bool) -> None:
    torch.manual_seed(0)
    paired = PairedQNetworks(11, 32, 5, DuelingDQN if dueling else AgentDQN)
    x = torch.randn(2, 7, 11)
    q_values, logits = paired(x)
    for index in range(2):
        agent = paired.agent(index)
        assert isinstance(agent, DuelingDQN if dueling else AgentDQN)
        agent_q, agent_message = agent(x[index])
        torch.testing.assert_close(agent_q, q_values[index])
        torch.testing.assert_close(agent_message, torch.sigmoid(logits[index]))


def test_observation_mask_zeroes_the_hidden_inputs() -> None:
    obs = np.arange(1, 12, dtype=np.float32)
    independent = train.apply_observation_mask(obs, "independent")
    assert independent[9] == 0 and independent[10] == 0 and np.all(independent[:9] == obs[:9])
    comm = train.apply_observation_mask(torch.from_numpy(obs), "comm")
    assert comm[9] == 10 and comm[10] == 0
    np.testing.assert_array_equal(train.apply_observation_mask(obs[None], "full")[0], obs)
    with pytest.raises(ValueError, match="unknown mode"):
        train.apply_observation_mask(obs, "telepathy")


# ---------------------------------------------------------------------- configuration
def test_every_field_has_a_flag_in_both_spellings_with_its_help_text() -> None:
    flags = build_parser()._option_string_actions
    helps = field_help(TrainConfig)
    for spec in dataclasses.fields(TrainConfig):
        help_text = helps[spec.name]
        assert help_text and "\n" not in help_text, f"field {spec.name} has no one-line help"
        for flag in (f"--{spec.name}", f"--{spec.name.replace('_', '-')}"):
            assert flags[flag].dest == spec.name and flags[flag].help.startswith(help_text)


def test_starter_flags_and_defaults() -> None:
    cfg = parse_config([])
    assert (cfg.seed, cfg.mode, cfg.gamma, cfg.run_modes()) == (
        641,
        "all",
        0.99,
        ["independent", "comm", "full"],
    )
    assert cfg.run_seeds() == list(range(641, 651))  # 10 seeds per mode
    dashed = parse_config(
        [
            "--num-episodes",
            "7",
            "--batch-size",
            "8",
            "--learning-starts",
            "8",
            "--epsilon-decay",
            "0.3",
            "--seeds",
            "1",
            "2",
            "--grid-size",
            "6",
        ]
    )
    assert (dashed.num_episodes, dashed.batch_size, dashed.epsilon_decay) == (7, 8, 0.3)
    assert dashed.run_seeds() == [1, 2] and dashed.grid_size == 6
    assert parse_config(["--mode", "comm,full"]).run_modes() == ["comm", "full"]


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--mode", "telepathy"], "mode must be all or a comma-separated list"),
        (["--gamma", "1.0"], "gamma"),
        (["--n_step", "0"], "n_step"),
        (["--comm_learning", "maybe"], "comm_learning"),
        (["--epsilon_end", "0.5", "--epsilon_start", "0.1"], "epsilon_end"),
    ],
)
def test_invalid_settings_are_refused(flags: list[str], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_config(flags)


# ---------------------------------------------------------------------- trainer interface
def test_trainer_interface_methods() -> None:
    trainer = filled_trainer("full")
    state = trainer.rollout.obs[0, 0]
    action, comm = trainer.select_action(state, trainer.network_A, epsilon=0.0)
    assert type(action) is int and 0 <= action < 5
    assert type(comm) is float and 0.0 <= comm <= 1.0
    q_values, _ = trainer.network_A(torch.from_numpy(state)[None])
    assert action == int(q_values.argmax())
    assert {trainer.select_action(state, trainer.network_A, 1.0)[0] for _ in range(60)} == set(
        range(5)
    )
    loss = trainer.update_networks(32)
    assert type(loss) is float and np.isfinite(loss)
    reward, success = trainer.train_episode()
    assert type(reward) is float and type(success) is bool
    mean_reward, success_rate = trainer.evaluate(num_episodes=10)
    assert type(mean_reward) is float and 0.0 <= success_rate <= 1.0


def test_time_limit_is_not_terminal_for_learning() -> None:
    trainer = filled_trainer("full")
    stored = trainer.replay_buffer.get(np.arange(len(trainer.replay_buffer)))
    assert stored["done"].sum() == 0 or np.all(stored["reward"][stored["done"] == 1] == 10.0)
    # 20 steps x 16 envs, no episode lasts 50 steps: force a cut-off and check its label.
    collect(trainer, trainer.rollout.env.max_steps)
    stored = trainer.replay_buffer.get(np.arange(len(trainer.replay_buffer)))
    assert np.all((stored["done"] == 1) == (stored["reward"] == 10.0))


def message_head_gradient(trainer: train.MultiAgentTrainer) -> torch.Tensor:
    """Gradient of the TD loss with respect to agent B's message head. B's message enters
    only A's input, so this is the gradient of receiver A's loss."""
    batch = trainer.sample(64)
    trainer.online.zero_grad(set_to_none=True)
    loss, _, _ = trainer.td_loss(batch)
    loss.backward()
    gradient = trainer.online.stacked.message_head.weight.grad  # None: no path to the head
    return torch.zeros(trainer.cfg.hidden_dim) if gradient is None else gradient[1, 0]


@pytest.mark.parametrize("mode", ["comm", "full"])
def test_dial_trains_the_senders_message_head_through_the_receivers_loss(mode: str) -> None:
    assert message_head_gradient(filled_trainer(mode)).abs().sum() > 0


@pytest.mark.parametrize(
    ("mode", "extra"), [("independent", ()), ("full", ("--comm_learning", "none"))]
)
def test_no_message_gradient_without_dial(mode: str, extra: tuple[str, ...]) -> None:
    assert message_head_gradient(filled_trainer(mode, *extra)).abs().sum() == 0


# ---------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("p2smoke")
    train.main([*TINY, "--num_seeds", "1", "--workers", "1", "--output_dir", str(out)])
    return out


def test_smoke_run_writes_every_output(smoke_run: Path) -> None:
    models, logs = smoke_run / "agent_models", smoke_run / "training_logs"
    for mode in ("independent", "comm", "full"):
        for agent in "AB":
            assert (models / f"{mode}_seed641_agent_{agent}.pt").is_file()
            assert (models / f"{mode}_agent_{agent}.pt").is_file()
        rows = train.read_csv(logs / f"{mode}_seed641.csv")
        assert rows[-1]["env_steps"] >= 1536
        assert {"loss", "mean_q", "eval_success_greedy", "eval_success_eps"} <= set(rows[0])
        final = json.loads((logs / f"{mode}_seed641_selection.json").read_text())
        assert final["eps"]["episodes"] == 32
    assert json.loads((models / "hyperparameters.json").read_text())["total_steps"] == 1536
    np.testing.assert_array_equal(load_map(models / "map.json"), MultiAgentEnv(seed=641).grid)
    assert (logs / "training_curves.png").stat().st_size > 10_000
    assert not list(smoke_run.rglob(".*tmp*")), "temporary files left behind"


def test_exported_models_reproduce_the_trainer_and_carry_their_mask(tmp_path: Path) -> None:
    for mode in ("independent", "comm", "full"):
        trainer = filled_trainer(mode)
        trainer.update_networks(32)
        trainer.models_dir = tmp_path
        trainer.save_models()
        obs = torch.from_numpy(trainer.rollout.obs.transpose(1, 0, 2).copy())  # (2, N, 11)
        with torch.no_grad():
            expected_q, expected_logit = trainer.online(train.apply_observation_mask(obs, mode))
        for index, agent in enumerate("AB"):
            model = jit_load(tmp_path / f"{mode}_seed641_agent_{agent}.pt")
            q_values, comm = model(obs[index])
            torch.testing.assert_close(q_values, expected_q[index])
            torch.testing.assert_close(comm, torch.sigmoid(expected_logit[index]))
            changed = obs[index].clone()
            changed[:, 9] = torch.rand(len(changed))
            changed[:, 10] = torch.rand(len(changed))
            q_changed, _ = model(changed)
            if mode == "full":
                assert not torch.allclose(q_changed, q_values)
            else:
                changed_distance_only = obs[index].clone()
                changed_distance_only[:, 10] += 0.3
                torch.testing.assert_close(model(changed_distance_only)[0], q_values)
            if mode == "independent":
                torch.testing.assert_close(q_changed, q_values)


def test_same_seed_same_logs_and_models_in_parallel_and_in_sequence(tmp_path: Path) -> None:
    """A seed fixes a run, whichever process runs it. (Model files are compared by their
    weights: this test process has compiled other TorchScript types before, which renames
    the classes inside a file; a fresh process writes the same bytes every time.)"""
    args = [*TINY, "--mode", "comm", "--seeds", "3", "4"]
    train.main([*args, "--workers", "2", "--output_dir", str(tmp_path / "a")])
    train.main([*args, "--workers", "1", "--output_dir", str(tmp_path / "b")])
    for seed in (3, 4):
        for name in (
            f"training_logs/comm_seed{seed}.csv",
            f"training_logs/comm_seed{seed}_selection.json",
        ):
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
        for agent in "AB":
            name = f"agent_models/comm_seed{seed}_agent_{agent}.pt"
            weights = [jit_load(tmp_path / run / name).state_dict() for run in "ab"]
            assert weights[0].keys() == weights[1].keys()
            for key in weights[0]:
                assert torch.equal(weights[0][key], weights[1][key]), key
    logs = [(tmp_path / "a" / f"training_logs/comm_seed{s}.csv").read_text() for s in (3, 4)]
    assert logs[0] != logs[1]


def test_full_agents_learn_on_a_small_map(tmp_path: Path) -> None:
    """A 5 x 5 map, 30 k env steps (about 15 s): far above the random policy (about 3 %).

    The run is deterministic on one machine (0.93 here at ε = 0.05, 0.80 greedy); the bar
    leaves room for another CPU's floating-point rounding to change the trajectory."""
    flags = "--mode full --grid_size 5 --map_seed 3 --total_steps 30000 --num_envs 32"
    flags += " --learning_starts 2000 --eval_interval 5000 --epsilon_fraction 0.6 --batch_size 128"
    trainer = train.MultiAgentTrainer(
        MultiAgentEnv(grid_size=(5, 5), seed=3),
        parse_config([*flags.split(), "--output_dir", str(tmp_path)]),
    )
    trainer.train()
    _, success = trainer.evaluate(num_episodes=500, epsilon=0.05)
    eval_env = trainer.make_vector_env(500, None)
    random_success = evaluate_policy(eval_env, random_policy(0), 500)["success_rate"]
    assert success >= 0.5 and success >= 5 * random_success, (success, random_success)


@pytest.mark.parametrize(
    ("flag", "hint"),
    [
        (["--total_step", "1000"], "(did you mean --total_steps?)"),
        (["--num-episode", "5"], "(did you mean --num-episodes?)"),
        (["--map_pool", "5"], "(did you mean --map_seed?)"),  # a study's flag, not train.py's
    ],
)
def test_an_unknown_flag_is_one_line_with_the_closest_flag_and_the_help(
    flag: list[str], hint: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        train.main([*flag, "--output_dir", "unused"])
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.splitlines()
    assert lines == [
        f"train.py: error: unrecognized arguments: {' '.join(flag)} {hint}",
        "(see train.py --help)",
    ]
