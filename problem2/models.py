"""Q-networks with a message head (one agent's, and both agents' stacked for training), the
observation masks of the ablations, and the form a policy file holds: a network behind its
mask, written as TorchScript by :func:`export_policy` (byte-stable: the same weights give the
same file anywhere).

Both networks follow the assignment's formula with one hidden layer:
    h = ReLU(W1 x + b1),   Q = W_q h + b_q  (or DuelingDQN's form),   m = sigmoid(w_m·h + b_m)
"""

from __future__ import annotations

import copy
import hashlib
import io
import os
import warnings
import zipfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
from torch import nn
from vector_env import MASKED_INPUTS, OBSERVATION_DIM, positive_int


def observation_mask(mode: str, obs_dim: int = OBSERVATION_DIM) -> np.ndarray:
    """The multiplicative mask (obs_dim,) float32, read-only, of ablation ``mode``, used
    wherever a network sees an observation (acting, both TD passes, evaluation, inside
    exported policies). For a w x w window (obs_dim w² + 2) the message and the distance
    are elements w² and w² + 1. ValueError for an unknown mode."""
    if mode not in MASKED_INPUTS:
        raise ValueError(f"unknown mode {mode!r}; expected one of {sorted(MASKED_INPUTS)}")
    if obs_dim < 3:
        raise ValueError(f"obs_dim must be at least 3 (patch, message, distance), got {obs_dim}")
    mask = np.ones(obs_dim, dtype=np.float32)
    for index in MASKED_INPUTS[mode]:
        mask[index + obs_dim - OBSERVATION_DIM] = 0.0
    mask.flags.writeable = False
    return mask


class MessagingQNetwork(nn.Module):
    """Shared part: the size checks, the hidden ReLU layer, the sigmoid message head and
    ``forward``. Subclasses add the Q head(s) and define ``forward_with_logit(x) -> (q, logit)``."""

    def __init__(self, input_dim: int, hidden_dim: int, num_actions: int) -> None:
        super().__init__()
        sizes = {"input_dim": input_dim, "hidden_dim": hidden_dim, "num_actions": num_actions}
        for name, value in sizes.items():
            positive_int(value, name)
        self.hidden = nn.Linear(input_dim, hidden_dim)
        self.message_head = nn.Linear(hidden_dim, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` [B, input_dim] -> (Q-values [B, num_actions], message [B, 1] in [0, 1]);
        one observation ``x`` [input_dim] -> ([num_actions], [1])."""
        q_values, logit = self.forward_with_logit(x)
        return q_values, torch.sigmoid(logit)


class AgentDQN(MessagingQNetwork):
    """Q-values over ``num_actions`` actions and a message in [0, 1] from one hidden layer."""

    def __init__(self, input_dim: int = 11, hidden_dim: int = 64, num_actions: int = 5) -> None:
        super().__init__(input_dim, hidden_dim, num_actions)
        self.q_head = nn.Linear(hidden_dim, num_actions)

    def forward_with_logit(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` [B, input_dim] -> (Q-values [B, num_actions], message logit [B, 1]).

        DIAL training adds noise to the logit before the sigmoid."""
        hidden = torch.relu(self.hidden(x))
        return self.q_head(hidden), self.message_head(hidden)


class DuelingDQN(MessagingQNetwork):
    """Like :class:`AgentDQN`, but Q = V + (A − mean A) from separate value and advantage
    heads on the shared hidden layer."""

    def __init__(self, input_dim: int = 11, hidden_dim: int = 64, num_actions: int = 5) -> None:
        super().__init__(input_dim, hidden_dim, num_actions)
        self.value_head = nn.Linear(hidden_dim, 1)
        self.advantage_head = nn.Linear(hidden_dim, num_actions)

    def forward_with_logit(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` [B, input_dim] -> (Q-values [B, num_actions], message logit [B, 1])."""
        hidden = torch.relu(self.hidden(x))
        advantages = self.advantage_head(hidden)
        q_values = self.value_head(hidden) + advantages - advantages.mean(dim=-1, keepdim=True)
        return q_values, self.message_head(hidden)


class StackedLinear(nn.Module):
    """Two agents' ``nn.Linear`` layers as one: ``weight`` [2, out, in], ``bias`` [2, 1, out];
    ``x`` [2, B, in] (A's inputs, then B's) -> [2, B, out], one batched matrix product."""

    def __init__(self, layers: Sequence[nn.Linear]) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.stack([layer.weight.detach() for layer in layers]))
        self.bias = nn.Parameter(torch.stack([layer.bias.detach() for layer in layers])[:, None])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.baddbmm(self.bias, x, self.weight.transpose(1, 2))


class PairedQNetworks(nn.Module):
    """Both agents' networks as one module, for training: each keeps its own weights
    (independent learners) and one batched pass evaluates both. ``stacked`` is an AgentDQN (or
    DuelingDQN) whose layers are :class:`StackedLinear`, so the agent network's own
    ``forward_with_logit`` runs (the math is written once); :meth:`agent` returns one agent's
    slice as a plain network with identical outputs."""

    def __init__(
        self,
        input_dim: int,
        hidden_dim: int,
        num_actions: int,
        network_class: type[MessagingQNetwork],
    ) -> None:
        super().__init__()
        self.network_class = network_class
        self.sizes = (input_dim, hidden_dim, num_actions)
        # The initial weights are two interface networks' (PyTorch's nn.Linear default).
        agents = [self.network_class(*self.sizes) for _ in "AB"]
        self.stacked = copy.deepcopy(agents[0])
        for name, _ in agents[0].named_children():
            setattr(self.stacked, name, StackedLinear([getattr(a, name) for a in agents]))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` [2, B, D] (A's inputs, then B's) -> (Q [2, B, A], message logit [2, B, 1])."""
        return self.stacked.forward_with_logit(x)

    @torch.no_grad()
    def agent(self, index: int) -> MessagingQNetwork:
        """Agent ``index``'s network as a standalone AgentDQN / DuelingDQN (a copy)."""
        network = self.network_class(*self.sizes)
        for name, layer in network.named_children():
            stacked = getattr(self.stacked, name)
            layer.weight.copy_(stacked.weight[index])
            layer.bias.copy_(stacked.bias[index, 0])
        return network


# ------------------------------------------------ the form a policy file holds
# Their class paths are written into every policy file (:func:`export_policy`).
class _ExportLinear(nn.Module):
    """``nn.Linear`` without TorchScript constants. TorchScript writes a module's constants
    (``in_features``, ``out_features``) in set order, which follows Python's per-process
    string hashing, and caches compiled types per process; exporting this class instead
    makes the saved file depend on the weights only."""

    def __init__(self, linear: nn.Linear) -> None:
        super().__init__()
        self.weight = linear.weight
        self.bias = linear.bias

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return nn.functional.linear(x, self.weight, self.bias)


class MaskedPolicy(nn.Module):
    """A network behind a fixed multiplicative observation mask.

    ``forward(obs)`` takes raw observations [B, input_dim] (or one [input_dim]) and returns
    ``(q_values [B, A], comm_signal [B, 1])`` (without the batch dimension for one)."""

    def __init__(self, network: nn.Module, mask: torch.Tensor) -> None:
        super().__init__()
        self.network = network
        self.register_buffer("mask", mask)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if obs.dim() == 1:
            q_values, comm = self.network(obs.unsqueeze(0) * self.mask)
            return q_values.squeeze(0), comm.squeeze(0)
        return self.network(obs * self.mask)


def exportable_copy(network: nn.Module) -> nn.Module:
    """A CPU copy of ``network`` in eval mode without gradients, its ``nn.Linear`` layers
    replaced by :class:`_ExportLinear` (byte-stable TorchScript); ``network`` is untouched."""
    exported = copy.deepcopy(network).cpu().eval().requires_grad_(False)
    for name, child in list(exported.named_children()):
        if isinstance(child, nn.Linear):
            setattr(exported, name, _ExportLinear(child))
    return exported


@contextmanager
def quiet_torchscript() -> Iterator[None]:
    """torch 2.13 marks ``torch.jit`` deprecated, but the course requires TorchScript files
    that load with ``torch.jit.load`` alone, so the warning is expected here."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", r"`torch\.jit\.\w+` is deprecated", DeprecationWarning)
        yield


def export_policy(
    network: MessagingQNetwork,
    mask: str | Sequence[float] | np.ndarray | torch.Tensor,
    path: str | Path,
) -> Path:
    """Script ``network`` behind ``mask`` (an ablation name, for any input_dim, or input_dim
    numbers) and save it atomically with ``torch.jit.save``. ``network`` itself is left
    untouched (a CPU copy in eval mode is exported). Returns the path written."""
    input_dim = network.hidden.in_features
    if isinstance(mask, str):
        mask = observation_mask(mask, input_dim)
    elif isinstance(mask, torch.Tensor):
        mask = mask.detach().cpu().numpy()
    mask_tensor = torch.from_numpy(np.array(mask, dtype=np.float32)).flatten()  # a copy
    if mask_tensor.numel() != input_dim:
        raise ValueError(f"mask has {mask_tensor.numel()} elements; the network takes {input_dim}")
    return save_scripted(MaskedPolicy(exportable_copy(network), mask_tensor), path)


def save_scripted(module: nn.Module, path: str | Path) -> Path:
    """Script ``module`` and save it atomically, the same weights giving the same bytes
    anywhere (:func:`without_debug_sources`). Returns the path written."""
    # Saving to memory first keeps the archive's inner folder name fixed ("archive", not the
    # temporary file's name), so the same weights always give byte-identical files.
    buffer = io.BytesIO()
    with quiet_torchscript():
        torch.jit.save(torch.jit.script(module), buffer)
    final = Path(path)  # written aside, then renamed: never a half-written policy file
    final.parent.mkdir(parents=True, exist_ok=True)
    temporary = final.with_name(f".{final.name}.tmp.{os.getpid()}")
    try:
        temporary.write_bytes(without_debug_sources(buffer.getvalue()))
        os.replace(temporary, final)
    finally:
        temporary.unlink(missing_ok=True)
    return final


def without_debug_sources(archive: bytes) -> bytes:
    """Make a TorchScript archive depend on its content only: drop the ``*.debug_pkl``
    entries (source maps holding this file's absolute path, which ``torch.jit.load`` does not
    need), and replace the random per-process ``.data/serialization_id`` by 40 digits of a
    SHA-256 of the other entries, so equal weights give byte-identical files anywhere."""
    source = zipfile.ZipFile(io.BytesIO(archive))
    entries = [e for e in source.infolist() if not e.filename.endswith(".debug_pkl")]
    digest = hashlib.sha256()
    for entry in entries:
        if not entry.filename.endswith("serialization_id"):
            digest.update(entry.filename.encode() + source.read(entry.filename))
    content_id = str(int(digest.hexdigest(), 16))[:40].zfill(40).encode()
    output = io.BytesIO()
    with zipfile.ZipFile(output, "w", zipfile.ZIP_STORED) as stripped:
        for entry in entries:
            data = source.read(entry.filename)
            stripped.writestr(
                entry, content_id if entry.filename.endswith("serialization_id") else data
            )
    return output.getvalue()
