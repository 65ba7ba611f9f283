"""The map panel (``studies/panel.py``): the map property, Spearman's rho, the contrasts of
the modes' success, homing and arrivals on hand-made episodes, and the study's evaluation
end to end on tiny batches (structure, bad input, identical bytes on a rerun)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from analysis.arrivals import homing_counts, homing_shares
from analysis.episodes import target_distances
from analysis.stats import (
    average_ranks,
    mode_contrasts,
    mode_differences,
    spearman,
    spearman_interval,
)
from rollout import EpisodeResults
from studies import panel
from studies.panel import EFFECTS, PANEL_MAP_SEEDS, landmark_distance
from studies.panel_behaviour import arrival_measures
from vector_env import FREE, OBSTACLE, TARGET

from tests.conftest import ROOT, load_problem_module

DATA = Path(__file__).parent / "data"


def grid_with(target: tuple[int, int], obstacles: list[tuple[int, int]] = ()) -> np.ndarray:
    grid = np.full((10, 10), FREE)
    grid[target] = TARGET
    for cell in obstacles:
        grid[cell] = OBSTACLE
    return grid


def test_landmark_distance_is_zero_where_the_patch_shows_a_wall_or_an_obstacle() -> None:
    assert landmark_distance(grid_with((0, 0))) == 0  # a corner
    assert landmark_distance(grid_with((9, 4))) == 0  # by a wall
    assert landmark_distance(grid_with((4, 4), [(5, 5)])) == 0  # an obstacle diagonally next
    assert landmark_distance(grid_with((4, 4))) == 4  # open ground: off the grid 5 rows up
    assert landmark_distance(grid_with((4, 4), [(6, 2)])) == 1  # an obstacle 2 cells away
    assert landmark_distance(grid_with((2, 5), [(8, 8)])) == 2  # off the grid 3 rows up


def test_average_ranks_and_spearman_with_ties() -> None:
    assert average_ranks([10, 20, 20, 30]).tolist() == [1.0, 2.5, 2.5, 4.0]
    # By hand: ranks x (1, 2.5, 2.5, 4), y (1, 3, 2, 4); centred products 4.5 over
    # sqrt(4.5 * 5): 3 / sqrt(10).
    assert spearman([1, 2, 2, 3], [1, 3, 2, 4]) == pytest.approx(3 / np.sqrt(10))
    assert spearman([3, 2, 1], [1, 2, 3]) == pytest.approx(-1.0)
    assert spearman([1, 1, 1], [1, 2, 3]) is None  # undefined, never NaN


def test_spearman_interval_leaves_out_resamples_without_a_correlation() -> None:
    x, y = [0, 0, 0, 0, 1, 2], [0.1, -0.2, 0.0, 0.3, 0.5, 0.4]
    result = spearman_interval(x, y, n_resamples=2000, seed=3)
    assert result["rho"] == pytest.approx(spearman(x, y))
    assert 0 < result["undefined_resamples"] < 2000  # some resamples draw only x = 0
    low, high = result["ci95"]
    assert -1 <= low <= result["rho"] <= high <= 1
    json.dumps(result, allow_nan=False)
    constant = spearman_interval([1, 1, 1], [1, 2, 3], n_resamples=50)
    assert constant["rho"] is None and constant["ci95"] is None
    assert constant["undefined_resamples"] == 50


def successes_solving(share: float, seeds: int, episodes: int = 400) -> np.ndarray:
    """(seeds, episodes): every seed solves the first ``share`` of the episodes."""
    return np.tile(np.arange(episodes) < share * episodes, (seeds, 1))


def test_the_interaction_contrast_of_four_modes() -> None:
    successes = {
        "independent": successes_solving(0.2, 3),
        "comm": successes_solving(0.3, 4),
        "distance": successes_solving(0.25, 3),
        "full": successes_solving(0.6, 5),
    }
    result = mode_contrasts(successes, EFFECTS, n_resamples=2000)
    interaction = result["interaction"]
    assert interaction["mean"] == pytest.approx(0.6 - 0.3 - 0.25 + 0.2)
    # Identical seeds: only the episodes vary, and redrawing the seeds alone changes nothing.
    assert interaction["ci95_seeds_only"] == pytest.approx([0.25, 0.25])
    assert interaction["established"] and interaction["ci95"][0] > 0.15
    assert interaction["seeds"] == {"full": 5, "comm": 4, "distance": 3, "independent": 3}
    assert result["both"]["mean"] == pytest.approx(0.4)
    pairwise = mode_differences(successes, n_resamples=2000)["full_minus_independent"]
    for key in ("mean", "ci95", "ci95_seeds_only", "established"):
        assert pairwise[key] == result["both"][key]
    with pytest.raises(ValueError, match="contrast 'x'"):
        mode_contrasts(successes, {"x": {"full": 1.0, "nowhere": -1.0}})


def test_mode_differences_are_unchanged_by_the_contrasts() -> None:
    """The pairwise output, byte for byte, as written by mode_differences before it was
    built on mode_contrasts."""
    rng = np.random.default_rng(2024)
    successes = {
        mode: rng.random((seeds, 300)) < p
        for mode, seeds, p in (
            ("independent", 5, 0.4),
            ("comm", 4, 0.5),
            ("distance", 5, 0.45),
            ("full", 3, 0.7),
        )
    }
    result = mode_differences(successes, n_resamples=3000, chunk=700)
    expected = (DATA / "mode_differences_before_contrasts.json").read_text(encoding="utf-8")
    assert json.dumps(result, indent=1) + "\n" == expected


def corridor_episode(path_a: list[int], path_b: list[int], length: int) -> EpisodeResults:
    """One recorded episode on a 1 x 5 corridor (target at column 4): each agent's column
    at positions 0..T (T = len - 1), the episode ``length`` steps long."""
    positions = np.zeros((1, len(path_a), 2, 2), dtype=np.int64)
    positions[0, :, 0, 1], positions[0, :, 1, 1] = path_a, path_b
    success = np.array([path_a[length] == path_b[length] == 4])
    trajectories = {"positions": positions}
    return EpisodeResults(np.zeros(1), success, np.array([length]), trajectories)


def test_homing_counts_the_moves_made_while_the_partner_waits_on_the_target() -> None:
    corridor = np.array([[FREE, FREE, FREE, FREE, TARGET]])
    distances = target_distances(corridor)  # 4 3 2 1 0
    # B reaches the target after step 1; A then moves closer, stays, farther, closer,
    # closer; the last move (past the episode's length) does not count.
    episode = corridor_episode([0, 1, 2, 2, 1, 2, 3, 2], [3, 4, 4, 4, 4, 4, 4, 4], length=6)
    counts = homing_counts(episode, distances)
    assert counts.tolist() == [3, 1, 1]  # A's move 0 -> 1 came before B arrived
    assert homing_shares(counts) == pytest.approx({"closer": 0.6, "farther": 0.2, "neither": 0.2})
    assert homing_shares([0, 0, 0]) == {"closer": 0.0, "farther": 0.0, "neither": 0.0}


def test_arrival_measures_say_who_came_first_and_how_long_the_pair_took() -> None:
    episode = corridor_episode([2, 3, 3, 4, 4, 4], [3, 4, 4, 4, 4, 4], length=3)
    measures = arrival_measures(episode, (0, 4))
    assert measures["B_first"] == 1.0 and measures["A_first"] == 0.0
    assert measures["first_arrival_step"] == 1.0  # B on the target at position 1
    assert measures["steps_first_arrival_to_meeting"] == 2.0  # A arrives at position 3
    never = corridor_episode([0, 0, 0], [1, 1, 1], length=2)
    assert arrival_measures(never, (0, 4))["first_arrival_step"] is None


def test_the_makefile_trains_the_maps_of_the_rule() -> None:
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    maps = re.search(r"^PANEL_MAPS := (.*)$", makefile, re.MULTILINE)[1].split()
    assert tuple(int(m) for m in maps) == PANEL_MAP_SEEDS == (641, *range(11))


TINY_PANEL_FLAGS = (
    "--mode independent,full --num_seeds 1 --total_steps 1536 --num_envs 16 --learning_starts 512 "
    "--batch_size 32 --eval_interval 512 --eval_episodes 16 --final_eval_episodes 32 "
    "--buffer_size 4096 --workers 1"
)
TINY_PANEL = TINY_PANEL_FLAGS.split()
OUTPUTS = ("panel.json", "panel.csv", "panel_effects.png", "timing.json")


@pytest.fixture(scope="module")
def tiny_panel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Tiny batches of modes independent and full on maps 641 and 4 (one seed each)."""
    root = tmp_path_factory.mktemp("panel")
    train = load_problem_module("problem2", "train")  # in this process: the panel is under test
    for map_seed in (641, 4):
        train.main(
            [*TINY_PANEL, "--map_seed", str(map_seed), "--output_dir", str(root / f"map{map_seed}")]
        )
    return root


def run_panel(panel_dir: Path, *extra: str) -> dict:
    argv = ["--panel_dir", str(panel_dir), "--maps", "641,4", "--num_episodes", "40", *extra]
    return panel.main(argv)


def test_the_panel_evaluates_every_map_and_a_rerun_gives_the_same_bytes(
    tiny_panel: Path,
) -> None:
    results = run_panel(tiny_panel, "--workers", "1")
    first = {name: (tiny_panel / name).read_bytes() for name in OUTPUTS[:3]}
    assert json.loads(first["panel.json"]) == results
    assert list(results["maps"]) == ["641", "4"]
    entry = results["maps"]["4"]
    assert entry["target"] == [2, 6] and entry["landmark_distance"] == 2
    assert results["maps"]["641"]["landmark_distance"] == 0
    for condition in ("greedy", "eps"):
        assert list(entry["effects"][condition]) == ["both"]  # only full and independent
        both = entry["effects"][condition]["both"]
        assert both["verdict"] in ("gain", "loss", "unclear") and both["episodes"] == 40
        for mode in ("independent", "full"):
            rate = entry["success"][mode][condition]
            assert rate["per_seed"] == [rate["mean"]]
        assert both["mean"] == pytest.approx(
            entry["success"]["full"][condition]["mean"]
            - entry["success"]["independent"][condition]["mean"]
        )
    assert entry["references"]["oracle"]["success_rate"] == 1.0
    behaviour = entry["behaviour"]
    assert set(behaviour["modes"]) == {"independent", "full"}
    assert set(behaviour["modes"]["full"]["interventions"]) == {"message", "distance"}
    assert sum(behaviour["beacon_explorer"]["greedy"]["homing"]["counts"]) > 0
    assert results["correlations"]["both"]["maps"] == [641, 4]
    assert results["summary"]["eps"]["both"]["maps"] == 2
    rows = first["panel.csv"].decode("utf-8").splitlines()
    assert len(rows) == 3 and rows[1].startswith("641,8,1,0,")
    run_panel(tiny_panel, "--workers", "2")
    for name, content in first.items():
        assert (tiny_panel / name).read_bytes() == content, name
    assert not list(tiny_panel.glob(".*tmp*"))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--num_episodes", "0"], "--num_episodes must be an integer in 1..5000"),
        (["--maps", "641,x"], "argument --maps: expected integers, got '641,x'"),
        (["--maps", "4,4"], "distinct non-negative"),
        (["--workers", "0"], "--workers must be an integer in 1..64"),
        (["--maps", "641,7"], "map7"),
    ],
)
def test_bad_input_is_refused_before_any_work(
    tiny_panel: Path, tmp_path: Path, argv: list[str], message: str, capsys
) -> None:
    empty = tmp_path / "empty"
    for folder in ("map641", "map4"):  # a copy of the maps without any earlier output
        (empty / folder).mkdir(parents=True)
        for sub in ("agent_models", "training_logs"):
            (empty / folder / sub).symlink_to(tiny_panel / folder / sub)
    with pytest.raises(SystemExit):
        panel.main(["--panel_dir", str(empty), "--maps", "641,4", *argv])
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in empty.iterdir()) == ["map4", "map641"]  # nothing written


def test_a_batch_of_another_map_is_refused(tiny_panel: Path, tmp_path: Path, capsys) -> None:
    (tmp_path / "map5").symlink_to(tiny_panel / "map4")  # trained on map 4, filed as map 5
    with pytest.raises(SystemExit):
        panel.main(["--panel_dir", str(tmp_path), "--maps", "5"])
    assert "trained on map seed 4, not 5" in capsys.readouterr().err
