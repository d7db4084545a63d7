"""neuenh.allocator: the fit kernel's steps, which allocate and free the same activations every time,
take far fewer new pages once freed memory is kept than under glibc's defaults."""

import json
import platform
import subprocess
import sys

import pytest

from neuenh.allocator import keep_freed_memory

# Six correction candidates (low-rank) of one material on 6,666 samples — the validation split of
# a 10,000-sample adaptive fit — in a fresh process: the minor page faults of each of 12 gradient steps.
STEPS = """
import json, resource, sys
import torch
torch.set_num_threads(1)
from neuenh.allocator import keep_freed_memory
kept = keep_freed_memory() if sys.argv[1] == "keep" else None
from neuenh.data.samples import sample_materials
from neuenh.data.synthetic import synthetic_zoo
from neuenh.fit.capacity import CAPACITIES
from neuenh.fit.kernel import RowKernel, RowSpace, frozen
from neuenh.fit.layout import layout_rows, padded
from neuenh.materials import MaterialTable
from neuenh.models import get_model

model = get_model("ggx", state="00010001000", seed=3)
samples = sample_materials(synthetic_zoo(1, seed=5), 6666, seed=1)
space = RowSpace(model, CAPACITIES["low-rank"](model))
x = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim)).repeat(6, 1)
wi, wo, f_r, valid = padded(samples)
material = torch.zeros(6, dtype=torch.long)
layout = layout_rows(wi, wo, f_r, material, valid[material], torch.zeros(6, valid.shape[1], dtype=torch.bool))
kernel = RowKernel(model, space)
faults = []
with frozen(model):
    for _ in range(12):
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        kernel(x, layout, prior_strength=torch.full((6,), 1e-2))
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(json.dumps({"kept": kept, "faults": faults}))
"""


def _steps(mode: str) -> dict:
    run = subprocess.run([sys.executable, "-c", STEPS, mode], capture_output=True, text=True, check=True, timeout=300)
    return json.loads(run.stdout)


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                    reason="the setting is glibc's malloc's; other C libraries are left alone")
def test_fit_steps_take_far_fewer_new_pages_once_freed_memory_is_kept():
    """After the first step (which takes its pages either way): under glibc's defaults the steps take
    tens of thousands of pages anew (freed activations handed back and taken again); kept, far fewer.
    So the totals over the steps are compared, not single steps. Which steps take pages moves from run
    to run, both ways. Kept, a few steps take a few thousand while the heap grows to the largest step.
    By default, glibc's own dynamic mmap threshold sometimes settles after four steps. And a host
    that pages out cold memory (DAMON's `pageout`, on in these machines' VMs) makes even kept memory
    fault again. On an EPYC, steps 2-12 took 31,074-64,209 pages by default and 3,411-6,967 kept
    (docs/BENCHMARKS.md, "The C allocator's page faults"). Page faults, not time: a count does not
    depend on the machine's speed."""
    default, kept = _steps("default"), _steps("keep")
    assert kept["kept"] is True
    default_pages, kept_pages = sum(default["faults"][1:]), sum(kept["faults"][1:])
    assert default_pages > 20_000 and 2 * kept_pages < default_pages


@pytest.mark.parametrize("retain_bytes", [-1, 1 << 31])
def test_a_retained_size_mallopt_cannot_take_is_refused_by_name(retain_bytes):
    with pytest.raises(ValueError, match="retain_bytes"):
        keep_freed_memory(retain_bytes)
