"""Q-networks, the message head, observation masks and TorchScript export."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from analysis.runs import load_policy
from models import MASKED_INPUTS, AgentDQN, DuelingDQN, export_policy, observation_mask

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")


def test_agent_dqn_follows_the_formula() -> None:
    torch.manual_seed(0)
    network = AgentDQN()
    x = torch.randn(4, 11)
    hidden = torch.relu(x @ network.hidden.weight.T + network.hidden.bias)
    q_values, comm = network(x)
    assert torch.allclose(q_values, hidden @ network.q_head.weight.T + network.q_head.bias)
    logit = hidden @ network.message_head.weight.T + network.message_head.bias
    assert torch.allclose(comm, torch.sigmoid(logit))


def test_dueling_q_is_value_plus_centred_advantage() -> None:
    torch.manual_seed(0)
    network = DuelingDQN(hidden_dim=32)
    x = torch.randn(6, 11)
    hidden = torch.relu(network.hidden(x))
    value, advantage = network.value_head(hidden), network.advantage_head(hidden)
    q_values, _ = network(x)
    assert torch.allclose(q_values, value + advantage - advantage.mean(dim=1, keepdim=True))
    assert torch.allclose(q_values.mean(dim=1, keepdim=True), value, atol=1e-6)


@pytest.mark.parametrize("network_class", [AgentDQN, DuelingDQN])
def test_logit_method_matches_forward_and_trains_the_message_head(network_class) -> None:
    torch.manual_seed(0)
    network = network_class()
    x = torch.randn(5, 11)
    q_values, logit = network.forward_with_logit(x)
    q_forward, comm = network(x)
    assert torch.allclose(q_values, q_forward) and torch.allclose(torch.sigmoid(logit), comm)
    noisy_message = torch.sigmoid(logit + 0.5 * torch.randn_like(logit))  # DIAL-style
    noisy_message.sum().backward()
    assert network.message_head.weight.grad is not None
    assert network.message_head.weight.grad.abs().sum() > 0
    scripted = torch.jit.script(network)
    assert torch.allclose(scripted.forward_with_logit(x)[1], logit)


def test_observation_masks() -> None:
    ones = np.ones(11, dtype=np.float32)
    expected = {"independent": [9, 10], "comm": [10], "distance": [9], "full": []}
    assert set(MASKED_INPUTS) == set(expected)
    for mode, zeroed in expected.items():
        mask = observation_mask(mode)
        assert mask.dtype == np.float32 and mask.shape == (11,)
        assert np.flatnonzero(mask != ones).tolist() == zeroed
        assert not mask.flags.writeable
    with pytest.raises(ValueError, match="unknown mode"):
        observation_mask("both")


@pytest.mark.parametrize("network_class", [AgentDQN, DuelingDQN])
@pytest.mark.parametrize("mode", ["independent", "comm", "distance", "full"])
def test_export_round_trip_applies_the_mask(tmp_path: Path, network_class, mode: str) -> None:
    torch.manual_seed(1)
    network = network_class(hidden_dim=128)
    network.train()
    path = export_policy(network, mode, tmp_path / "models" / "agent_A.pt")
    assert path.is_file() and network.training  # the original is left as it was
    policy = load_policy(path)
    obs = torch.rand(8, 11)
    q_values, comm = policy(obs)
    mask = torch.from_numpy(observation_mask(mode).copy())
    expected_q, expected_comm = network(obs * mask)
    assert torch.allclose(q_values, expected_q) and torch.allclose(comm, expected_comm)
    single_q, single_comm = policy(obs[0])
    assert single_q.shape == (5,) and single_comm.shape == (1,)
    assert torch.allclose(single_q, expected_q[0])
    for hidden in MASKED_INPUTS[mode]:  # masked elements cannot change the output
        changed = obs.clone()
        changed[:, hidden] += 5.0
        assert torch.allclose(policy(changed)[0], q_values)


def test_export_accepts_a_custom_mask(tmp_path: Path) -> None:
    network = AgentDQN()
    mask = [1.0] * 9 + [0.0, 1.0]
    policy = load_policy(export_policy(network, torch.tensor(mask), tmp_path / "p.pt"))
    obs = torch.rand(3, 11)
    assert torch.allclose(policy(obs)[0], network(obs * torch.tensor(mask))[0])


def test_export_rejects_a_mask_of_the_wrong_length(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="mask has 10 elements"):
        export_policy(AgentDQN(), [1.0] * 10, tmp_path / "p.pt")
    assert not any(tmp_path.iterdir())


def test_load_policy_names_a_missing_or_corrupt_file(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        load_policy(tmp_path / "missing.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"this is not a TorchScript archive")
    with pytest.raises(ValueError, match="corrupt.pt"):
        load_policy(corrupt)
    truncated = tmp_path / "truncated.pt"
    export_policy(AgentDQN(), "full", truncated)
    truncated.write_bytes(truncated.read_bytes()[:200])
    with pytest.raises(ValueError, match="truncated.pt"):
        load_policy(truncated)


def test_export_is_byte_reproducible_and_free_of_local_paths(tmp_path: Path) -> None:
    torch.manual_seed(3)
    network = AgentDQN()
    first, second = tmp_path / "first.pt", tmp_path / "second.pt"
    export_policy(network, "comm", first)
    export_policy(network, "comm", second)
    assert first.read_bytes() == second.read_bytes()
    assert str(Path(__file__).resolve().parents[2]).encode() not in first.read_bytes()
    obs = torch.rand(4, 11)
    q_values, _ = load_policy(first)(obs)
    expected, _ = network(obs * torch.tensor([1.0] * 10 + [0.0]))
    torch.testing.assert_close(q_values, expected)


def test_export_is_byte_identical_across_processes(tmp_path: Path) -> None:
    # torch writes a random serialization id per process; the export replaces it by a hash.
    script = (
        "import sys, torch; torch.manual_seed(3)\n"
        "from models import AgentDQN, export_policy\n"
        "export_policy(AgentDQN(), 'full', sys.argv[1])\n"
    )
    problem2 = Path(__file__).resolve().parents[2] / "problem2"
    paths = [tmp_path / "a.pt", tmp_path / "b.pt"]
    for path in paths:
        subprocess.run([sys.executable, "-c", script, str(path)], cwd=problem2, check=True)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert load_policy(paths[0])(torch.zeros(11))[0].shape == (5,)


PRODUCT = """
import hashlib, sys
sys.path.insert(0, sys.argv[1])
import torch
{setup}
torch.set_num_threads(1)
g = torch.Generator().manual_seed(0)
a, b = torch.randn(2, 128, 11, generator=g), torch.randn(2, 11, 128, generator=g)
c = torch.randn(256, 300, generator=g) @ torch.randn(300, 200, generator=g)
digest = hashlib.sha256((a @ b).numpy().tobytes() + c.numpy().tobytes()).hexdigest()
print(os.environ.get("MKL_CBWR"), digest)
"""


def test_reproducible_matmul_gives_the_bytes_of_mkl_cbwr_avx2_and_import_sets_nothing() -> None:
    """A process that calls safety.use_reproducible_matmul() before its first matrix
    product computes the bytes of a process started with MKL_CBWR=AVX2, whatever the CPU's own
    code path; importing the modules alone changes no environment variable."""
    problem2 = str(Path(__file__).resolve().parents[2] / "problem2")
    clean = {k: v for k, v in os.environ.items() if k != "MKL_CBWR"}

    def run(setup: str, env: dict[str, str]) -> str:
        code = PRODUCT.format(setup="import os\n" + setup)
        result = subprocess.run(
            [sys.executable, "-c", code, problem2],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        )
        return result.stdout.strip()

    assert run("import models\nimport safety", clean).startswith("None ")
    called = run("import safety\nsafety.use_reproducible_matmul()", clean)
    assert called.startswith("AVX2 ")
    assert called == run("", clean | {"MKL_CBWR": "AVX2"})


def test_every_entry_point_asks_for_reproducible_matmul_first() -> None:
    """Each module of problem2 that runs as a program calls use_reproducible_matmul() as
    the first statement of its main()."""
    root = Path(__file__).resolve().parents[2] / "problem2"
    programs = [
        p
        for p in sorted(root.rglob("*.py"))
        if "results" not in p.parts and '__name__ == "__main__"' in p.read_text(encoding="utf-8")
    ]
    assert len(programs) >= 10
    for path in programs:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        main = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "main")
        body = [
            s
            for s in main.body
            if not (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant))
        ]
        first = body[0]
        assert isinstance(first, ast.Expr) and isinstance(first.value, ast.Call), path
        func = first.value.func  # use_reproducible_matmul() or safety.use_reproducible_matmul()
        assert getattr(func, "id", getattr(func, "attr", None)) == "use_reproducible_matmul", path
