"""The NBRDF baseline: one small network fitted to each material (Sztrajman, Rainer, Ritschel,
Weyrich 2021, "Neural BRDF Representation and Importance Sampling", CGF 40(6), Sec. 4).

    x   = [half vector at phi_h = 0, difference vector]     (6)  ``data.nbrdf.network_input``
    h1  = relu(x W1 + b1);  h2 = relu(h1 W2 + b2)               (21, 21)
    f_r = exp(h2 W3 + b3) - 1                                   (3, RGB)

The same 6-21-21-3 architecture and input as the published MERL networks (``data/nbrdf.py``), but
fitted here, per material, to exactly the measurements every other model of the comparison gets,
with the comparison's loss (``train.log_l1``, the loss NBRDF itself uses). Optimiser (ours: the
paper trains with Adam, lr 5e-4, batches of 512 for many more samples): Adam, lr 5e-3 with a cosine
decay to 1e-3 of it, batches of 512, Glorot-uniform weights and zero biases as in its Keras code.
675 weights per material, no shared weights.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Mapping, Sequence

import torch
from torch import nn

from ..data.nbrdf import network_input
from ..data.samples import Samples
from ..optimizers import Adam, CosineSchedule
from ..train import log_l1

__all__ = ["NBRDFConfig", "NBRDFFit", "NBRDFNetwork", "fit_nbrdf"]


class NBRDFNetwork(nn.Module):
    """One material's network; ``forward`` gives the raw f_r (n, 3), ``evaluate`` the BRDF."""

    def __init__(self, hidden: int = 21, seed: int = 0):
        super().__init__()
        self.layers = nn.Sequential(nn.Linear(6, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                    nn.Linear(hidden, 3))
        generator = torch.Generator().manual_seed(seed)
        for layer in self.layers:
            if isinstance(layer, nn.Linear):
                with torch.no_grad():
                    bound = (6.0 / (layer.in_features + layer.out_features)) ** 0.5  # Glorot uniform
                    layer.weight.uniform_(-bound, bound, generator=generator)
                    layer.bias.zero_()

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        return torch.expm1(self.layers(network_input(wi, wo).float()))

    @torch.no_grad()
    def evaluate(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """f_r (n, 3) without the cosine, clipped at 0, and 0 unless both directions are above."""
        above = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)
        return torch.where(above, self(wi, wo).clamp_min(0.0), 0.0)

    def n_weights(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def state(self) -> dict[str, list[float]]:
        """The weights as flat lists of floats by ``state_dict`` name (a scene plan's parameters)."""
        return {name: [float(x) for x in p.detach().reshape(-1)] for name, p in self.state_dict().items()}

    @classmethod
    def from_state(cls, state: Mapping[str, Sequence[float]]) -> "NBRDFNetwork":
        """The network ``state()`` wrote (its width read from the first layer's size); a ValueError
        naming what does not fit."""
        try:
            net = cls(hidden=len(state["layers.0.weight"]) // 6)
            shapes = {k: v.shape for k, v in net.state_dict().items()}
            net.load_state_dict({k: torch.tensor(state[k], dtype=torch.float32).reshape(shapes[k]) for k in shapes})
        except (KeyError, RuntimeError, TypeError, ValueError) as exc:
            raise ValueError(f"not the weights of an NBRDF network ({type(exc).__name__}: {exc})") from None
        return net.eval()

    @classmethod
    def from_published(cls, weights: Mapping[str, Sequence]) -> "NBRDFNetwork":
        """A published network (``neuenh.data.nbrdf.NBRDFMaterial.weights``: ``W1`` (6 x H) ... ``b3``,
        (in, out) as in its authors' code) as this module, which evaluates it as that reader does."""
        layers = [torch.as_tensor(weights[k], dtype=torch.float32) for k in ("W1", "b1", "W2", "b2", "W3", "b3")]
        return cls.from_state({f"layers.{2 * i}.{kind}": (t.t() if kind == "weight" else t).reshape(-1).tolist()
                               for i in range(3) for kind, t in zip(("weight", "bias"), layers[2 * i : 2 * i + 2])})


@dataclass(frozen=True)
class NBRDFConfig:
    epochs: int = 300
    lr: float = 5e-3
    batch_size: int = 512
    hidden: int = 21


@dataclass
class NBRDFFit:
    networks: list[NBRDFNetwork]  # one per material, in ``samples.names`` order
    losses: list[float]  # per material, mean log-L1 on its fitted samples
    wall_s: float


def fit_nbrdf(samples: Samples, config: NBRDFConfig = NBRDFConfig(), seed: int = 0) -> NBRDFFit:
    """Fit one network per material of ``samples`` to its rows, independently."""
    start = time.perf_counter()
    networks, losses = [], []
    for m in range(len(samples.names)):
        rows = (samples.material == m).nonzero().flatten()
        if len(rows) == 0:
            raise ValueError(f"material {samples.names[m]!r} has no samples to fit")
        wi, wo, f_r = samples.wi[rows], samples.wo[rows], samples.f_r[rows]
        net = NBRDFNetwork(config.hidden, seed=seed + m)
        optimizer = Adam(net.parameters(), lr=config.lr)
        schedule = CosineSchedule(optimizer, config.epochs, config.lr * 1e-3)
        generator = torch.Generator().manual_seed(seed + m)
        for _ in range(config.epochs):
            order = torch.randperm(len(rows), generator=generator)
            for lo in range(0, len(rows), config.batch_size):
                index = order[lo : lo + config.batch_size]
                loss = log_l1(net(wi[index], wo[index]), f_r[index], wi[index]).mean()
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
            schedule.step()
        with torch.no_grad():
            losses.append(float(log_l1(net(wi, wo), f_r, wi).double().mean()))
        networks.append(net.eval())
    return NBRDFFit(networks, losses, time.perf_counter() - start)
