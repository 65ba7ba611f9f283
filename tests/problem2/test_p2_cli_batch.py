"""A training batch's result folder: one batch's, described by its manifest, installed whole
or not at all, never mixed with another batch, cleaned of stale temporaries, and left
consistent when the batch is interrupted or its parent process is killed."""

from __future__ import annotations

import hashlib
import io
import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import output_folder
import pytest
from batch.plumbing import ProgressLine, run_jobs
from output_folder import remove_stale_temporaries
from rollout import select_best
from settings import SettingError

from tests.conftest import PROBLEM2, load_problem_module

train = load_problem_module("problem2", "train")

TINY_FLAGS = (
    "--total_steps 1536 --num_envs 16 --learning_starts 512 --batch_size 32 --eval_interval 512 "
    "--eval_episodes 16 --final_eval_episodes 32 --buffer_size 4096 --target_update 20 "
    "--mode full --workers 1"
)
TINY = TINY_FLAGS.split()


def snapshot(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


@pytest.fixture(scope="module")
def batch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished batch: full mode, seeds 1 and 2, written with a relative --output_dir."""
    base = tmp_path_factory.mktemp("batch")
    cwd = Path.cwd()
    os.chdir(base)
    try:
        train.main([*TINY, "--seeds", "1", "2", "--output_dir", "out"])
    finally:
        os.chdir(cwd)
    return base / "out"


def test_manifest_describes_the_batch_and_matches_its_files(batch: Path) -> None:
    models = batch / "agent_models"
    manifest = json.loads((models / "manifest.json").read_text(encoding="utf-8"))
    assert manifest["format"] == 1
    assert (manifest["modes"], manifest["seeds"]) == (["full"], [1, 2])
    assert (manifest["map_seed"], manifest["reward_mode"]) == (641, "goal")
    hyperparameters = json.loads((models / "hyperparameters.json").read_text(encoding="utf-8"))
    assert manifest["hyperparameters"] == hyperparameters
    assert "output_dir" not in hyperparameters and "workers" not in hyperparameters
    assert hyperparameters["total_steps"] == 1536
    assert "code_version" not in manifest  # the batch and its files; the code is git's
    assert sorted(manifest["runs"]) == ["full_seed1", "full_seed2"]
    for name, run in manifest["runs"].items():
        for agent in "AB":
            data = (models / run["models"][agent]).read_bytes()
            assert hashlib.sha256(data).hexdigest() == run["sha256"][agent]
        selection = json.loads((batch / "training_logs" / f"{name}_selection.json").read_text())
        assert selection["validation_seed"] == 6_000_000 and selection["eps"]["episodes"] == 32
        for condition in ("greedy", "eps"):
            recorded = run["selection"][condition]
            assert recorded["success_rate"] == selection[condition]["success_rate"]
            assert (
                recorded["mean_steps_to_success"] == selection[condition]["mean_steps_to_success"]
            )
    best = manifest["best"]["full"]
    seeds = sorted(manifest["runs"])  # full_seed1, full_seed2
    pairs = [
        (manifest["runs"][n]["selection"]["greedy"], manifest["runs"][n]["selection"]["eps"])
        for n in seeds
    ]
    assert best == seeds[select_best(pairs, manifest["hyperparameters"]["select_by"])]
    for agent in "AB":
        assert (models / f"full_agent_{agent}.pt").read_bytes() == (
            models / f"{best}_agent_{agent}.pt"
        ).read_bytes()
    assert (models / "map.json").is_file() and (batch / "training_logs" / "timing.json").is_file()


def test_no_absolute_path_and_no_temporary_left_in_the_outputs(batch: Path) -> None:
    base = str(batch.parent)
    for path in batch.rglob("*"):
        assert not path.name.startswith("."), path
        if path.suffix in (".json", ".csv"):
            assert base not in path.read_text(encoding="utf-8"), path
    assert sorted(p.name for p in batch.iterdir()) == ["agent_models", "training_logs"]


def test_a_custom_run_inside_the_repository_ignores_itself(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--output_dir my_run`` from problem2/ is never offered to ``git add``; the results
    folder and folders outside the repository get no .gitignore."""
    monkeypatch.setattr(output_folder, "REPOSITORY", tmp_path)
    train.main([*TINY, "--seeds", "1", "--output_dir", str(tmp_path / "my_run")])
    ignore = (tmp_path / "my_run" / ".gitignore").read_text(encoding="utf-8")
    assert ignore.splitlines()[-1] == "*"
    output_folder.keep_out_of_git(tmp_path / "results" / "x", tmp_path / "results")
    assert not (tmp_path / "results" / "x" / ".gitignore").exists()


def test_batch_with_other_settings_is_refused_then_replaced_with_overwrite(
    batch: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    shutil.copytree(batch, out)
    before = snapshot(out)
    with pytest.raises(SystemExit) as exit_info:
        train.main([*TINY, "--seeds", "3", "--output_dir", str(out)])
    assert exit_info.value.code == 2
    message = capsys.readouterr().err
    assert "argument --output_dir" in message and "--overwrite" in message
    assert "seeds [1, 2] -> [3]" in message
    assert snapshot(out) == before
    train.main([*TINY, "--seeds", "3", "--output_dir", str(out), "--overwrite"])
    models = sorted(p.name for p in (out / "agent_models").glob("*_seed*"))
    assert models == ["full_seed3_agent_A.pt", "full_seed3_agent_B.pt"]  # no stale runs
    assert sorted(p.name for p in (out / "training_logs").glob("*.csv")) == ["full_seed3.csv"]


def test_rerun_with_identical_settings_replaces_and_removes_stale_temporaries(
    batch: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    shutil.copytree(batch, out)
    pid = dead_pid()
    (out / f".staging.{pid}" / "agent_models").mkdir(parents=True)
    (out / f".staging.{pid}" / "agent_models" / "full_seed9_agent_A.pt").write_bytes(b"x")
    (out / "agent_models" / f".full_agent_A.pt.tmp.{pid}").write_bytes(b"half")
    (out / "training_logs" / f".timing.json.tmp.{pid}").write_bytes(b"{")
    train.main([*TINY, "--seeds", "1", "2", "--output_dir", str(out)])
    assert not [p for p in out.rglob(".*")], "stale temporaries left"
    assert (
        snapshot(out)["agent_models/manifest.json"]
        == (batch / "agent_models" / "manifest.json").read_bytes()
    )


def test_stale_cleanup_spares_running_processes(tmp_path: Path) -> None:
    mine = tmp_path / f".staging.{os.getpid()}"
    stale = tmp_path / f".staging.{dead_pid()}"
    for folder in (mine, stale):
        folder.mkdir()
    (tmp_path / "results.json").write_text("{}", encoding="utf-8")
    assert remove_stale_temporaries(tmp_path) == [stale]
    assert mine.is_dir() and (tmp_path / "results.json").is_file()


def test_non_default_settings_do_not_go_into_the_default_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    default = tmp_path / "results"
    monkeypatch.setattr(train, "DEFAULT_OUTPUT_DIR", default)
    # Like the README's example (made tiny): it must not overwrite the default results.
    flags = [*TINY, "--seeds", "641", "642"]
    with pytest.raises(SystemExit) as exit_info:
        train.main([*flags, "--output_dir", str(default)])
    assert exit_info.value.code == 2
    message = capsys.readouterr().err
    assert "default results folder" in message and "--output_dir" in message
    assert "--overwrite" in message and "total_steps 300000 -> 1536" in message
    assert not default.exists()


def test_results_without_manifest_are_not_mixed_with_a_new_batch(tmp_path: Path, capsys) -> None:
    (tmp_path / "old" / "agent_models").mkdir(parents=True)
    (tmp_path / "old" / "agent_models" / "full_seed2_agent_A.pt").write_bytes(b"old")
    with pytest.raises(SystemExit):
        train.main([*TINY, "--seeds", "1", "--output_dir", str(tmp_path / "old")])
    assert "without a manifest.json" in capsys.readouterr().err


def test_a_failing_run_leaves_the_previous_batch_and_no_new_folder(
    batch: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_train_one = train.train_one

    def second_run_fails(cfg, mode, seed, *args):  # noqa: ANN001, ANN202
        if seed == 2:
            raise RuntimeError("injected failure")
        return real_train_one(cfg, mode, seed, *args)

    monkeypatch.setattr(train, "train_one", second_run_fails)
    out = tmp_path / "out"
    shutil.copytree(batch, out)
    before = snapshot(out)
    with pytest.raises(RuntimeError, match="injected failure"):
        train.main([*TINY, "--seeds", "1", "2", "--output_dir", str(out)])
    assert snapshot(out) == before
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    fresh = tmp_path / "new" / "deeper"
    with pytest.raises(RuntimeError, match="injected failure"):
        train.main([*TINY, "--seeds", "1", "2", "--output_dir", str(fresh)])
    assert not (tmp_path / "new").exists()


# ------------------------------------------------------------ signals (real processes)
def start_parallel_training(out: Path) -> subprocess.Popen:
    """A two-worker batch long enough to be interrupted while it writes."""
    flags = TINY[:-4] + ["--total_steps", "400000", "--mode", "comm", "--seeds", "1", "2"]
    return subprocess.Popen(
        [sys.executable, str(PROBLEM2 / "train.py"), *flags, "--workers", "2"]
        + ["--output_dir", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        # As from a terminal: a test suite started in the background by a shell inherits
        # SIGINT ignored, and Python then keeps ignoring it.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def wait_for_rows(out: Path, process: subprocess.Popen, rows: int = 3) -> None:
    """Until both runs have logged ``rows`` evaluation rows in the staging folder."""
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        logs = list(out.glob(".staging.*/training_logs/comm_seed*.csv"))
        if len(logs) == 2 and all(len(p.read_text().splitlines()) > rows for p in logs):
            return
        assert process.poll() is None, process.stderr.read().decode()
        time.sleep(0.2)
    raise AssertionError("the training never logged its rows")


def children_of(pid: int) -> list[int]:
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            children.append(int(stat.parent.name))
    return children


def running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc (Linux)")
def test_workers_stop_when_the_parent_is_killed(tmp_path: Path) -> None:
    out = tmp_path / "out"
    process = start_parallel_training(out)
    wait_for_rows(out, process)
    workers = children_of(process.pid)
    assert len(workers) >= 2  # the pool's workers (and multiprocessing's resource tracker)
    process.kill()  # SIGKILL: no handler runs in the parent
    process.wait()
    deadline = time.monotonic() + 10
    while any(running(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [pid for pid in workers if running(pid)], "orphaned workers keep running"
    assert not (out / "agent_models").exists()  # the staging folder was never installed


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ctrl_c_keeps_the_measured_rows_and_leaves_the_results_untouched(tmp_path: Path) -> None:
    out = tmp_path / "out"
    process = start_parallel_training(out)
    wait_for_rows(out, process)
    os.killpg(process.pid, signal.SIGINT)  # as Ctrl-C in a terminal: the whole group
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr.decode()
    assert "interrupted: the rows measured so far are in" in stderr.decode()
    assert sorted(p.name for p in out.iterdir()) == ["interrupted"]
    for seed in (1, 2):
        rows = train.read_csv(out / "interrupted" / "1" / "training_logs" / f"comm_seed{seed}.csv")
        assert len(rows) >= 3 and rows[0]["env_steps"] == 0


def refused_setting(value: int, progress_sink: object) -> None:
    """A job of ``run_jobs`` whose settings are refused (run in a worker process)."""
    raise SettingError("total_steps", "must be at least learning_starts 5000", value)


def test_a_setting_refused_in_a_worker_reaches_the_parent_whole() -> None:
    """A worker's error crosses the process boundary by pickling; an exception that cannot
    be rebuilt from its pickle stops the pool's result thread and the batch waits forever."""
    error = SettingError("lr", "must be > 0", -1.0, ("gamma", "must be in [0, 1]", 2.0))
    assert pickle.loads(pickle.dumps(error)).problems == error.problems
    with pytest.raises(SettingError) as raised:
        run_jobs(refused_setting, [(3000,), (4000,)], 2, ProgressLine(2, 0, stream=io.StringIO()))
    assert raised.value.problems == [("total_steps", "must be at least learning_starts 5000", 3000)]
