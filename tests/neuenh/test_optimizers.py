"""The written-out optimisers against ``torch.optim`` itself (the independent reference): the same
parameters, bit for bit, after every step of a small network's training under a cosine schedule;
and a process that trains and fits with them never imports ``torch._dynamo``, which is why they exist."""

import subprocess
import sys

import pytest
import torch

from neuenh.optimizers import Adam, CosineSchedule, RMSProp

CASES = {  # ours, torch's, with the settings the project trains and fits with
    "rmsprop": (lambda p: RMSProp(p, lr=1e-2, alpha=0.9), lambda p: torch.optim.RMSprop(p, lr=1e-2, alpha=0.9)),
    "adam": (lambda p: Adam(p, lr=5e-3), lambda p: torch.optim.Adam(p, lr=5e-3)),
}


def network(seed: int) -> torch.nn.Module:
    torch.manual_seed(seed)
    return torch.nn.Sequential(torch.nn.Linear(4, 16), torch.nn.LeakyReLU(), torch.nn.Linear(16, 3),
                               torch.nn.Linear(3, 3))  # the last layer is frozen for the first steps


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("schedule", [False, True])
def test_the_same_parameters_as_torch_optim_after_every_step(case, schedule):
    ours_of, theirs_of = CASES[case]
    nets = network(0), network(0)
    optimisers = ours_of(list(nets[0].parameters())), theirs_of(list(nets[1].parameters()))
    steps = 40
    schedules = (CosineSchedule(optimisers[0], steps, 1e-5),
                 torch.optim.lr_scheduler.CosineAnnealingLR(optimisers[1], T_max=steps, eta_min=1e-5)) \
        if schedule else ()
    g = torch.Generator().manual_seed(1)
    x, y = torch.randn(64, 4, generator=g) * 3, torch.randn(64, 3, generator=g)
    for step in range(steps + 2):  # two past the schedule's end: torch's special case there
        for net, optimiser in zip(nets, optimisers):
            net[2].requires_grad_(step >= 5)  # a parameter without a gradient keeps its value and state
            optimiser.zero_grad()
            (net(x[step % 4 :: 4]) - y[step % 4 :: 4]).abs().mean().backward()
            optimiser.step()
        for s in schedules:
            s.step()
        for a, b in zip(nets[0].parameters(), nets[1].parameters()):
            assert torch.equal(a, b), (case, step)
        if schedule:
            assert optimisers[0].lr == schedules[1].get_last_lr()[0], step
    assert not torch.equal(nets[0][2].weight, network(0)[2].weight), "the frozen layer never trained"


def test_bad_settings_name_themselves():
    with pytest.raises(ValueError, match="no parameters"):
        RMSProp([], lr=1e-3)
    with pytest.raises(ValueError, match="learning rate must not be negative, not -0.1"):
        Adam([torch.zeros(1, requires_grad=True)], lr=-0.1)
    with pytest.raises(ValueError, match="steps must not be negative, not -1"):
        CosineSchedule(Adam([torch.zeros(1, requires_grad=True)]), -1)
    idle = CosineSchedule(Adam([torch.zeros(1, requires_grad=True)]), 0)  # a run of no epochs builds one
    with pytest.raises(ValueError, match="0 steps cannot step"):
        idle.step()


def test_training_and_fitting_never_import_torch_dynamo():
    """A candidate trained, a material fitted by the paper's protocol and by NBRDF, in a fresh
    process: ``torch.optim`` would import ``torch._dynamo`` (~1 s) at the first optimiser."""
    script = """
import sys
from neuenh.checkpoint import Bundle
from neuenh.data.samples import TrainingData, sample_materials
from neuenh.data.synthetic import synthetic_ggx
from neuenh.fit.protocols import PaperRMSProp
from neuenh.study.nbrdf_fit import NBRDFConfig, fit_nbrdf
from neuenh.train import TrainConfig, train_candidate
samples = sample_materials(synthetic_ggx(2, seed=0), 200, seed=0)
data = TrainingData(*samples.split(0.1, seed=0))
parent = Bundle.initial("ggx", samples.names)
train_candidate(parent, "00010000000", data, TrainConfig(epochs=1, lr_final=1e-4), seed=0)
PaperRMSProp(epochs=1).fit(parent.model, samples)
fit_nbrdf(samples, NBRDFConfig(epochs=1))
print("torch._dynamo" in sys.modules)
"""
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "False"
