"""Both agents' Q-networks as one stacked module, for fast training on a CPU.

Each agent keeps its own weights (independent learners), but the two networks are
evaluated in one batched matrix product, and all their weights live in a single
flat parameter, so that the optimiser step and the gradient clipping are one tensor
operation each instead of a dozen. Callers just write ``networks(x)``; how the weights
are stored stays inside this class.

``agent(i)`` turns agent ``i``'s slice back into a plain :class:`models.AgentDQN`
(or :class:`models.DuelingDQN`) with identical outputs, for export and for the
interface methods that take one network.
"""

from __future__ import annotations

import math

import torch
from models import AgentDQN, DuelingDQN, MessagingQNetwork
from torch import nn

NUM_AGENTS = 2


class PairedQNetworks(nn.Module):
    """Two one-hidden-layer Q-networks with message heads, stacked along a leading axis.

    Shapes (agent axis first): ``hidden_weight`` [2, H, D], ``hidden_bias`` [2, 1, H],
    ``head_weight`` [2, K, H], ``head_bias`` [2, 1, K], where the K head outputs are the
    ``num_actions`` Q-values (or advantages), then the state value for the dueling form,
    then the message logit.
    """

    def __init__(
        self, input_dim: int = 11, hidden_dim: int = 64, num_actions: int = 5, dueling: bool = False
    ) -> None:
        super().__init__()
        self.input_dim, self.hidden_dim, self.num_actions = input_dim, hidden_dim, num_actions
        self.dueling = dueling
        self.head_dim = num_actions + (2 if dueling else 1)
        shapes = {
            "hidden_weight": (NUM_AGENTS, hidden_dim, input_dim),
            "hidden_bias": (NUM_AGENTS, 1, hidden_dim),
            "head_weight": (NUM_AGENTS, self.head_dim, hidden_dim),
            "head_bias": (NUM_AGENTS, 1, self.head_dim),
        }
        self._shapes = list(shapes.values())
        self._sizes = [torch.Size(shape).numel() for shape in self._shapes]
        self.flat = nn.Parameter(torch.empty(sum(self._sizes)))
        self._detached: tuple[torch.Tensor, ...] | None = None
        self._gradient_views: tuple[torch.Tensor, ...] | None = None
        # Same initialisation as the interface classes (PyTorch's nn.Linear default).
        self.load_agents(
            [self._network_class()(input_dim, hidden_dim, num_actions) for _ in range(NUM_AGENTS)]
        )

    def _network_class(self) -> type[MessagingQNetwork]:
        return DuelingDQN if self.dueling else AgentDQN

    def weights(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The four weight tensors (shapes in the class docstring) as views of ``flat``.

        Without gradient tracking (acting, evaluation, TD targets) the views are made once
        and reused: making them costs about as much as a forward pass."""
        if torch.is_grad_enabled():
            return self._views_of(self.flat)
        if self._detached is None or self._detached[0].data_ptr() != self.flat.data_ptr():
            self._detached = self._views_of(self.flat.detach())
        return self._detached

    def gradients(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Views of ``flat.grad`` shaped like :meth:`weights` (allocated at the first call,
        made once), for a hand-written backward pass that writes the gradient in place."""
        if self.flat.grad is None:
            self.flat.grad = torch.zeros_like(self.flat)
            self._gradient_views = None
        if self._gradient_views is None or (
            self._gradient_views[0].data_ptr() != self.flat.grad.data_ptr()
        ):
            self._gradient_views = self._views_of(self.flat.grad)
        return self._gradient_views

    @torch.no_grad()
    def clip_grad_norm_(self, max_norm: float) -> torch.Tensor:
        """Scale the gradient to Euclidean norm at most ``max_norm``, as
        ``torch.nn.utils.clip_grad_norm_`` does (with the same 1e-6); returns the norm before.
        One flat gradient makes it two small operations instead of a loop over tensors."""
        grad = self.flat.grad
        norm = torch.linalg.vector_norm(grad)
        grad.mul_(torch.clamp(max_norm / (norm + 1e-6), max=1.0))
        return norm

    def clip_divisor(self, max_norm: float) -> torch.Tensor:
        """The number (a 0-d tensor) to divide the gradient by to clip it as
        :meth:`clip_grad_norm_` does: max(1, (norm + 1e-6) / max_norm). Passed to
        :meth:`FlatAdam.step`, the clipping happens inside the optimiser's one operation.
        (No autograd is involved: a gradient never requires grad.)"""
        norm = torch.linalg.vector_norm(self.flat.grad)
        return norm.add_(1e-6).div_(max_norm).clamp_min_(1.0)

    def _views_of(self, flat: torch.Tensor) -> tuple[torch.Tensor, ...]:
        pieces = torch.split(flat, self._sizes)
        return tuple(p.view(s) for p, s in zip(pieces, self._shapes, strict=True))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` [2, B, D] (A's inputs, then B's) -> (Q [2, B, A], message logit [2, B, 1])."""
        hidden_weight, hidden_bias, head_weight, head_bias = self.weights()
        hidden = torch.baddbmm(hidden_bias, x, hidden_weight.transpose(1, 2)).relu_()
        heads = torch.baddbmm(head_bias, hidden, head_weight.transpose(1, 2))
        logits = heads[..., -1:]
        if not self.dueling:
            return heads[..., : self.num_actions], logits
        advantages = heads[..., : self.num_actions]
        value = heads[..., self.num_actions : self.num_actions + 1]
        return value + advantages - advantages.mean(dim=-1, keepdim=True), logits

    @torch.no_grad()
    def agent(self, index: int) -> MessagingQNetwork:
        """Agent ``index``'s network as a standalone AgentDQN / DuelingDQN (a copy)."""
        hidden_weight, hidden_bias, head_weight, head_bias = (v[index] for v in self.weights())
        network = self._network_class()(self.input_dim, self.hidden_dim, self.num_actions)
        network.hidden.weight.copy_(hidden_weight)
        network.hidden.bias.copy_(hidden_bias[0])
        for head, rows in self._head_rows(network).items():
            head.weight.copy_(head_weight[rows])
            head.bias.copy_(head_bias[0, rows])
        return network

    @torch.no_grad()
    def load_agents(self, networks: list[MessagingQNetwork]) -> None:
        """Copy two standalone networks into the stacked weights."""
        hidden_weight, hidden_bias, head_weight, head_bias = self.weights()
        for index, network in enumerate(networks):
            hidden_weight[index].copy_(network.hidden.weight)
            hidden_bias[index, 0].copy_(network.hidden.bias)
            for head, rows in self._head_rows(network).items():
                head_weight[index, rows].copy_(head.weight)
                head_bias[index, 0, rows].copy_(head.bias)

    def _head_rows(self, network: MessagingQNetwork) -> dict[nn.Linear, slice]:
        """Which rows of the stacked head belong to which head of ``network``."""
        actions = slice(0, self.num_actions)
        message = slice(self.head_dim - 1, self.head_dim)
        if self.dueling:
            value = slice(self.num_actions, self.num_actions + 1)
            return {
                network.advantage_head: actions,
                network.value_head: value,
                network.message_head: message,
            }
        return {network.q_head: actions, network.message_head: message}


class FlatAdam:
    """Adam (Kingma & Ba, 2015) for one flat parameter, computed as ``torch.optim.Adam``
    computes it (no weight decay): m <- β1 m + (1 − β1) g, v <- β2 v + (1 − β2) g²,
    θ <- θ − lr / (1 − β1^t) · m / (sqrt(v / (1 − β2^t)) + eps).

    One fused operation per step where PyTorch has it (the kernel of
    ``torch.optim.Adam(fused=True)``), else seven: for the ~2 k weights of both agents, the
    per-step bookkeeping of ``torch.optim`` costs more than this arithmetic.
    ``param_groups[0]["lr"]`` may be changed between steps, as with a torch optimiser."""

    def __init__(
        self,
        param: torch.Tensor,
        lr: float,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        self.param, self.betas, self.eps = param, betas, eps
        self.param_groups = [{"lr": lr}]
        self.exp_avg = torch.zeros_like(param, memory_format=torch.contiguous_format)
        self.exp_avg_sq = torch.zeros_like(self.exp_avg)
        self.steps = 0
        self.step_tensor = torch.zeros(())  # the step count, as the fused kernel reads it
        self.fused = hasattr(torch, "_fused_adam_")
        self._param_data = param.detach()  # the same storage, for the fused kernel

    def zero_grad(self) -> None:
        if self.param.grad is not None:
            self.param.grad.zero_()

    def step(self, grad_divisor: torch.Tensor | None = None) -> None:
        """One Adam step; the gradient is first divided (in place) by ``grad_divisor``, a
        0-d tensor, if given (gradient clipping: :meth:`PairedQNetworks.clip_divisor`).
        It works on the parameter's detached data, so it needs no ``torch.no_grad``."""
        grad, (beta1, beta2) = self.param.grad, self.betas
        self.steps += 1
        if self.fused:
            self.step_tensor.add_(1.0)
            torch._fused_adam_(
                [self._param_data], [grad], [self.exp_avg], [self.exp_avg_sq], [],
                [self.step_tensor], lr=self.param_groups[0]["lr"], beta1=beta1, beta2=beta2,
                weight_decay=0.0, eps=self.eps, amsgrad=False, maximize=False,
                grad_scale=grad_divisor, found_inf=None,
            )  # fmt: skip
            return
        if grad_divisor is not None:
            grad.div_(grad_divisor)
        self.exp_avg.lerp_(grad, 1.0 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1.0 - beta2)
        bias_correction1 = 1.0 - beta1**self.steps
        bias_correction2 = 1.0 - beta2**self.steps
        denominator = self.exp_avg_sq.sqrt().div_(math.sqrt(bias_correction2)).add_(self.eps)
        step_size = self.param_groups[0]["lr"] / bias_correction1
        self._param_data.addcdiv_(self.exp_avg, denominator, value=-step_size)
