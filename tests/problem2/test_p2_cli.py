"""train.py's command line: every bad setting is a usage error naming the flag and the value
before any work starts; list flags in both forms; --help; progress output; cp1252 consoles;
relative paths against the current folder."""

from __future__ import annotations

import dataclasses
import io
import os
import subprocess
import sys
from pathlib import Path

import pytest
from batch.plumbing import ProgressLine
from settings import SettingError, TrainConfig, field_help, validated
from studies.one_step.beacon import BeaconConfig
from studies.pool_training import PoolConfig

from tests.conftest import PROBLEM2, load_problem_module

train = load_problem_module("problem2", "train")
parse_config = train.parse_config

TINY_FLAGS = (
    "--total_steps 1536 --num_envs 16 --learning_starts 512 --batch_size 32 --eval_interval 512 "
    "--eval_episodes 16 --final_eval_episodes 32 --buffer_size 4096 --target_update 20"
)
TINY = TINY_FLAGS.split()

# (flags, the value the message must echo); the flag is always the first argument.
BAD_SETTINGS = [
    (["--mode", "full,full"], "full,full"),
    (["--mode", "full", "full"], "full,full"),
    (["--mode", "ful"], "ful"),
    (["--mode", "Full"], "Full"),
    (["--mode", "all,full"], "all,full"),
    (["--seed", "-1"], "-1"),
    (["--num_seeds", "0"], "0"),
    (["--num_seeds", "2.5"], "2.5"),
    (["--seeds", "-1"], "-1"),
    (["--seeds", "641,641"], "641 641"),
    (["--seeds", "641,x"], "x"),
    (["--map_seed", "-1"], "-1"),
    (["--map_seed", "-3"], "-3"),
    (["--grid_size", "2"], "2"),
    (["--grid_size", "10", "10", "10"], "10 10 10"),
    (["--grid_size", "1000"], "1000"),
    (["--max_steps", "0"], "0"),
    (["--reward_mode", "literal"], "literal"),
    (["--total_steps", "-100"], "-100"),
    (["--total_steps", "0"], "0"),
    (["--num_episodes", "-5"], "-5"),
    (["--num_envs", "0"], "0"),
    (["--batch_size", "0"], "0"),
    (["--lr", "inf"], "inf"),
    (["--lr", "nan"], "nan"),
    (["--lr", "0"], "0"),
    (["--lr_end_factor", "-1"], "-1"),
    (["--lr_end_factor", "2"], "2"),
    (["--gamma", "1"], "1"),
    (["--gamma", "-0.1"], "-0.1"),
    (["--epsilon_start", "1.5"], "1.5"),
    (["--epsilon_end", "-0.1"], "-0.1"),
    (["--epsilon_end", "0.5", "--epsilon_start", "0.1"], "0.5"),
    (["--epsilon_decay", "1"], "1"),
    (["--epsilon_decay", "1.5"], "1.5"),
    (["--epsilon_decay", "-0.5"], "-0.5"),
    (["--epsilon_fraction", "0"], "0"),
    (["--hidden_dim", "0"], "0"),
    (["--target_update", "-1"], "-1"),
    (["--target_tau", "-0.25"], "-0.25"),
    (["--target_tau", "1.5"], "1.5"),
    (["--buffer_size", "10"], "10"),
    (["--learning_starts", "0"], "0"),
    (["--learning_starts", "10", "--batch_size", "32"], "10"),
    (["--updates_per_step", "0"], "0"),
    (["--max_grad_norm", "0"], "0"),
    (["--max_grad_norm", "-1"], "-1"),
    (["--max_grad_norm", "inf"], "inf"),
    (["--comm_learning", "maybe"], "maybe"),
    (["--comm_noise", "-1"], "-1"),
    (["--comm_noise", "nan"], "nan"),
    (["--eval_interval", "0"], "0"),
    (["--eval_episodes", "0"], "0"),
    (["--select_by", "loss"], "loss"),
    (["--final_eval_episodes", "0"], "0"),
    (["--save_freq", "-1"], "-1"),
    (["--workers", "0"], "0"),
]


@pytest.mark.parametrize(
    ("flags", "echo"), BAD_SETTINGS, ids=lambda v: " ".join(v) if isinstance(v, list) else None
)
def test_bad_setting_is_a_usage_error_naming_flag_and_value_before_any_work(
    flags: list[str], echo: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_info:
        train.main([*flags, "--output_dir", str(out)])
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert "usage:" not in error and f"argument {flags[0]}" in error.replace("/--", " --")
    assert error.splitlines()[-1] == "(see train.py --help)"
    assert echo in error.splitlines()[-2]
    assert not out.exists()


def test_every_bad_setting_is_reported_not_only_the_first(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_info:
        train.main(["--gamma", "2", "--lr", "-1", "--output_dir", str(out)])
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.splitlines()
    assert lines[-3].endswith("argument --lr: must be a finite number in (0, inf), got -1.0")
    assert lines[-2] == "argument --gamma: must be a finite number in [0, 1), got 2.0"
    assert not out.exists()


def test_a_relation_is_checked_beside_single_settings_but_not_on_an_invalid_one() -> None:
    with pytest.raises(SettingError) as error:
        validated(TrainConfig(gamma=2.0, epsilon_start=0.1, epsilon_end=0.5))
    assert [name for name, _, _ in error.value.problems] == ["gamma", "epsilon_end"]
    assert (error.value.name, error.value.value) == ("gamma", 2.0)  # the first problem
    assert (
        str(error.value).splitlines()[1] == "epsilon_end must not exceed epsilon_start 0.1, got 0.5"
    )
    with pytest.raises(SettingError) as error:
        validated(TrainConfig(epsilon_start=2.0, epsilon_end=0.5))  # no comparison with 2.0
    assert [name for name, _, _ in error.value.problems] == ["epsilon_start"]


def test_output_dir_that_is_a_file_is_refused(tmp_path: Path, capsys) -> None:
    file = tmp_path / "a_file"
    file.write_text("x", encoding="utf-8")
    with pytest.raises(SystemExit):
        train.main(["--output_dir", str(file)])
    assert "argument --output_dir: must be a folder, not a file" in capsys.readouterr().err


def test_settings_from_python_are_checked_too() -> None:
    for bad in ({"lr": "0.1"}, {"keep_best": 1}, {"eval_episodes": 2.0}, {"seeds": [1, True]}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            validated(TrainConfig(**bad))


def test_list_flags_accept_spaces_and_commas_and_every_flag_its_dashed_spelling() -> None:
    assert parse_config(["--seeds", "641", "642"]).run_seeds() == [641, 642]
    assert parse_config(["--seeds", "641,642"]).run_seeds() == [641, 642]
    assert parse_config(["--seeds", "641,642", "643"]).run_seeds() == [641, 642, 643]
    assert parse_config(["--mode", "comm", "full"]).run_modes() == ["comm", "full"]
    assert parse_config(["--mode", "comm,full"]).mode == "comm,full"
    assert parse_config(["--grid_size", "10", "10"]).grid_size == 10
    assert parse_config(["--grid-size", "10"]).grid_size == 10
    assert parse_config(["--grid_size", "8,10"]).grid_shape() == (8, 10)
    assert parse_config(["--epsilon-decay", "0.995"]).epsilon_decay == 0.995
    assert parse_config(["--epsilon-fraction", "0.3"]).epsilon_fraction == 0.3
    assert parse_config(["--target-tau", "0.02"]).target_tau == 0.02
    assert parse_config(["--target_update", "250"]).target_update == 250
    assert parse_config(["--no-keep-best"]).keep_best is False


def test_skeleton_grid_size_list_means_the_same_grid() -> None:
    assert validated(TrainConfig(grid_size=[10, 10])).grid_size == 10
    assert validated(TrainConfig(grid_size=[6, 9])).grid_shape() == (6, 9)


def test_workers_default_to_the_available_cores() -> None:
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert TrainConfig().workers == cores


def run_train(args: list[str], cwd: Path, encoding: str | None = None, timeout: float = 300):
    env = dict(os.environ)
    if encoding:
        env["PYTHONIOENCODING"] = encoding
    return subprocess.run(
        [sys.executable, str(PROBLEM2 / "train.py"), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        timeout=timeout,
    )


def test_help_states_units_ranges_path_rule_and_overwrite_rule(tmp_path: Path) -> None:
    result = run_train(["--help"], cwd=tmp_path, encoding="cp1252")
    assert result.returncode == 0, result.stderr
    text = " ".join(result.stdout.decode("cp1252").split())
    for phrase in (
        "--grid_size N [N ...]",
        "--seeds SEED [SEED ...]",
        "gradient updates (not episodes, not env steps)",
        "multiplicative factor in (0, 1)",
        "relative to the current folder",
        "default: problem2/results",
        "refuses unless --overwrite",
        "interrupted/<n>/training_logs",
        "(default: 641)",
    ):
        assert phrase in text, phrase
    assert not list(tmp_path.iterdir())


def test_console_without_utf8_gets_replacement_characters_not_a_crash() -> None:
    code = "import safety; safety.make_console_safe(); print('ε → ×')"
    env = dict(os.environ, PYTHONIOENCODING="cp1252")
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=PROBLEM2, env=env, capture_output=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.decode("cp1252").strip() == "? ? ×"


def test_a_run_under_cp1252_writes_relative_to_the_current_folder(tmp_path: Path) -> None:
    args = [*TINY, "--mode", "full", "--seeds", "5", "--workers", "1", "--output_dir", "rel"]
    result = run_train(args, cwd=tmp_path, encoding="cp1252")
    assert result.returncode == 0, result.stderr.decode("cp1252")
    assert (tmp_path / "rel" / "agent_models" / "manifest.json").is_file()
    assert not (PROBLEM2 / "rel").exists()
    assert "\r" not in result.stderr.decode("cp1252")  # not a terminal: plain progress lines


class FakeStream(io.StringIO):
    def __init__(self, terminal: bool) -> None:
        super().__init__()
        self.terminal = terminal

    def isatty(self) -> bool:
        return self.terminal


ROW = {"env_steps": 5000, "epsilon": 0.5, "eval_success_eps": 0.25, "eval_success_greedy": 0.5}


def test_progress_line_fits_the_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("shutil.get_terminal_size", lambda *a, **k: os.terminal_size((60, 20)))
    stream = FakeStream(terminal=True)
    progress = ProgressLine(3, 100_000, stream=stream)
    progress.put(("independent_seed641", ROW, 1.0))
    progress.close()
    updates = stream.getvalue().split("\r")[1:]
    assert updates and all(len(update.rstrip("\n")) == 59 for update in updates)


def test_progress_without_terminal_prints_a_plain_line_every_interval() -> None:
    now = [0.0]
    stream = FakeStream(terminal=False)
    progress = ProgressLine(1, 10_000, stream=stream, clock=lambda: now[0], interval=10.0)
    for second in range(26):
        now[0] = float(second)
        progress.put(("full_seed1", ROW | {"env_steps": 100 * second}, now[0]))
    progress.close()
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue()
    assert len(lines) == 4  # at 0, 10 and 20 s, and the final line
    assert lines[-1].startswith("[0/1 runs] 2,500/10,000 env steps")


def test_every_setting_is_declared_with_its_check_and_help() -> None:
    for config in (TrainConfig, PoolConfig, BeaconConfig):
        helps = field_help(config)
        for spec in dataclasses.fields(config):
            assert callable(spec.metadata["check"]), spec.name
            assert len(helps[spec.name]) > 10, spec.name  # the docstring under the field


def test_a_setting_without_a_check_is_refused_before_its_value_is_read() -> None:
    @dataclasses.dataclass
    class Unchecked(TrainConfig):
        extra: int = dataclasses.field(default=1)
        """no check"""

    with pytest.raises(TypeError, match="no check for the setting extra of Unchecked"):
        validated(Unchecked())
