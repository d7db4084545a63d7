"""neuenh.fit.jit: the Dr.Jit kernel against the float64 torch kernel, on hard directions, and as every
protocol's ``kernel``."""

import copy

import pytest
import torch

from neuenh.data.samples import sample_materials
from neuenh.data.synthetic import synthetic_zoo
from neuenh.fit import Adaptive, FitOptions, LatentAdam, PlainLBFGS, fit_materials
from neuenh.fit.jit import JIT_FACTOR_READS, JIT_MIN_WORK, JitRowKernel, available, row_kernel, set_jit_threads
from neuenh.fit.kernel import LayerCorrection, RowKernel, RowSpace
from neuenh.fit.layout import layout_rows, padded
from neuenh.materials import MaterialTable
from neuenh.models import get_model
from neuenh.pretrained import load_model
from ggx_states import PAPER_STATE, small_ggx
from random_tables import random_table

needs_drjit = pytest.mark.skipif(not available(), reason="Dr.Jit's LLVM backend is not available (pip install "
                                "drjit, the neuenh[export] extra; libLLVM 17+: make mitsuba)")

MODELS = {  # every kind of position the kernel folds: formulas, modules of directions, operator modules; small
    # modules but the shipped model's, which is checked as it is
    "plain ggx": lambda: get_model("ggx", state="00000000000", seed=0),
    "paper state": lambda: small_ggx(PAPER_STATE, seed=1),
    "F and S*D*F": lambda: small_ggx("00010001000", seed=3),
    "ward": lambda: get_model("ward", seed=0),
    "shipped (alternatives)": lambda: load_model("enhanced-ggx")[0],
}


@pytest.fixture(scope="module")
def zoo():
    return sample_materials(synthetic_zoo(2, seed=5), 600, seed=1)


def assert_the_torch_kernel_to_float32_rounding(model, space: RowSpace, x: torch.Tensor, zoo, **call) -> None:
    """Rows ``x`` of both zoo materials and a second row of material 1 (``x[1:] + 0.1``), a held-out fold
    of every 4th sample, in one pass and in chunks of slots: losses per row and per sample, the objective
    and its gradient each within 4x the float32 torch kernel's own distance to the float64 one (plus a few
    ulps), so the two differ by rounding alone (the order of sums, fused multiply-adds, Dr.Jit's log)."""
    wi, wo, f_r, valid = padded(zoo)
    train, val = valid.clone(), torch.zeros_like(valid)
    train[:, ::4], val[:, ::4] = False, valid[:, ::4]
    layout = layout_rows(wi, wo, f_r, torch.tensor([0, 1, 1]), train[[0, 1, 1]], val[[0, 1, 1]])
    x = torch.cat([x, x[1:] + 0.1])
    double = copy.deepcopy(model).double()
    layout64 = layout_rows(wi.double(), wo.double(), f_r.double(), layout.material, layout.train, layout.val)
    call64 = {k: v.double() if isinstance(v, torch.Tensor) else v for k, v in call.items()}
    exact = RowKernel(double, RowSpace(double, space.corrections))(x.double(), layout64, **call64)
    torch32 = RowKernel(model, space)(x, layout, **call)
    eps = torch.finfo(torch.float32).eps
    kernel = JitRowKernel(model, space)
    if space.corrections:
        assert exact.grad[:, space.base_dim :].abs().max() > 1e-3  # the corrections' gradient is there to compare
    for chunk_slots in (10_000, 97):  # one pass; in chunks of slots (bounded memory, as RowKernel)
        jit = kernel(x, layout, chunk_slots=chunk_slots, **call)
        for field in ("train", "val", "objective", "per_sample", "grad"):
            ours, theirs, truth = (getattr(r, field).double() for r in (jit, torch32, exact))
            assert (ours - truth).abs().max() <= 4 * (theirs - truth).abs().max() + 16 * eps * truth.abs().max(), \
                (field, chunk_slots)
    assert kernel(x, layout, grad=False, **call).grad is None


@needs_drjit
@pytest.mark.parametrize("surrogate_eps", [None, 1e-2])
@pytest.mark.parametrize("name", MODELS)
def test_the_jit_kernel_is_the_torch_kernel_to_float32_rounding(name, surrogate_eps, zoo):
    model = MODELS[name]()
    space = RowSpace(model)
    assert_the_torch_kernel_to_float32_rounding(model, space, space.from_table(random_table(model, zoo.names, 0)), zoo,
                                                surrogate_eps=surrogate_eps)


CORRECTIONS = {  # dense and low-rank, folded first layers and operator modules, two corrections of one layer
    "last layers": lambda m: [LayerCorrection(p, len(module.layers) - 1) for p, module in m.neural.items()],
    "rank 2 everywhere": lambda m: [LayerCorrection(p, i, 2) for p, module in m.neural.items()
                                    for i in range(len(module.layers))],
    "dense first and a sum": lambda m: [LayerCorrection("F", 0), LayerCorrection("S*D*F", 0),
                                        LayerCorrection("F", 1), LayerCorrection("F", 1, 3)],
}


@needs_drjit
@pytest.mark.parametrize("corrections", CORRECTIONS)
def test_rows_with_corrections_are_the_torch_kernels_to_float32_rounding(corrections, zoo):
    """Rows with per-row corrections of the modules' weights, deltas away from zero, the prior weighed
    per row: every column of the gradient (analytical, latent, the corrections' factors) included."""
    model = MODELS["F and S*D*F"]()
    space = RowSpace(model, CORRECTIONS[corrections](model))
    x = space.from_table(random_table(model, zoo.names, 0), seed=3)
    x[:, space.base_dim :] += 0.05 * torch.randn(len(x), space.n_corrections, generator=torch.Generator().manual_seed(0))
    assert_the_torch_kernel_to_float32_rounding(model, space, x, zoo, prior_strength=torch.tensor([1e-2, 1e-1, 1.0]))


@needs_drjit
@pytest.mark.parametrize("corrections", [None, "last layers"])
def test_one_compiled_kernel_serves_every_number_of_rows_and_slots(corrections, zoo):
    """A fit calls its kernel on layouts of many shapes (each stage's starts, the narrowing, several
    materials at once): the compiled code reads no count of rows or slots, so a layout of another shape
    launches only kernels already compiled (with a count in the code, every shape compiled anew: on the
    shipped model 11 compiles, 24-28 s of build, for a first latent fit of one material; docs/BENCHMARKS.md,
    "Stop 81")."""
    import drjit as dr

    model = MODELS["F and S*D*F"]()
    space = RowSpace(model, CORRECTIONS[corrections](model) if corrections else ())
    x = space.from_table(random_table(model, zoo.names, 0), seed=3)
    wi, wo, f_r, valid = padded(zoo)
    kernel = JitRowKernel(model, space)

    def launched(rows: list[int], slots: int) -> set[str]:
        layout = layout_rows(wi, wo, f_r, torch.tensor(rows), valid[rows], torch.zeros_like(valid[rows]))
        dr.kernel_history()  # empties it
        kernel(x[rows], layout.chunk(0, slots), prior_strength=torch.full((len(rows),), 1e-2))
        return {entry["hash"] for entry in dr.kernel_history() if entry["type"] == dr.KernelType.JIT}

    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        first = launched([0], wi.shape[1])
        assert first, "no kernel launched"
        for rows, slots in (([0, 1, 1], wi.shape[1]), ([1, 0], 97), ([0, 1, 0, 1, 1], 250)):
            assert launched(rows, slots) <= first, (rows, slots)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)


@needs_drjit
def test_a_step_repeats_to_the_bit_on_every_thread():
    """Two calls with the same rows give the same losses and gradients, bit for bit, on two threads: each
    row's gradient is summed over its samples in a fixed order (a scatter of the samples' gradients into
    the rows' values adds them in the order the threads ran, and a fit would not repeat)."""
    import drjit as dr

    zoo = sample_materials(synthetic_zoo(2, seed=5), 3000, seed=1)
    model = MODELS["F and S*D*F"]()
    space = RowSpace(model, [LayerCorrection(p, len(module.layers) - 1) for p, module in model.neural.items()])
    wi, wo, f_r, valid = padded(zoo)
    layout = layout_rows(wi, wo, f_r, torch.tensor([0, 1]), valid, torch.zeros_like(valid))
    x = space.from_table(random_table(model, zoo.names, 0), seed=2)
    x[:, space.base_dim :] += 0.01 * torch.randn(x[:, space.base_dim :].shape, generator=torch.Generator().manual_seed(3))
    threads = dr.thread_count()
    set_jit_threads(2)
    try:
        kernel = JitRowKernel(model, space)
        first, *again = (kernel(x, layout, prior_strength=torch.full((2,), 1e-2)) for _ in range(6))
    finally:
        set_jit_threads(threads)
    for repeat in again:
        assert torch.equal(repeat.grad, first.grad) and torch.equal(repeat.per_sample, first.per_sample)


@needs_drjit
@pytest.mark.parametrize("rows, slots", [(1, 3000), (1, 50_000), (3, 20_000), (2, 7)])
def test_each_rows_gradient_sum_is_the_same_to_the_bit_column_by_column_or_stacked(rows, slots):
    """Each row's sum of its samples' gradient columns is the same to the bit at one torch thread, where
    large calls sum each column where Dr.Jit left it, and at two, where the columns are stacked and torch
    sums them with one thread per output, as before stop 82: so a fit's end points do not depend on the
    path. Values of both signs over a few orders of magnitude, where a sum's order shows in its bits."""
    import drjit as dr
    from drjit.llvm.ad import Float

    from neuenh.fit.jit import COLUMN_SUM_SAMPLES, _row_sums, _sample_columns

    generator = torch.Generator().manual_seed(rows * slots)
    columns = []
    for _ in range(5):
        values = torch.randn(rows * slots, generator=generator) * torch.exp(
            torch.empty(rows * slots).uniform_(-4, 4, generator=generator))
        columns.append(Float(values))
    dr.eval(columns)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        stacked = _sample_columns(columns, rows, slots).sum(2).t()
        at_two = _row_sums(columns, rows, slots)
        torch.set_num_threads(1)
        at_one = _row_sums(columns, rows, slots)
    finally:
        torch.set_num_threads(threads)
    assert stacked.shape == (rows, 5) and torch.isfinite(stacked).all()
    assert torch.equal(at_one, stacked) and torch.equal(at_two, stacked)
    if rows * slots >= COLUMN_SUM_SAMPLES:  # there the sums compared at one thread were column by column,
        # and another order of the same sums (the slots reversed) is not the same to the bit
        reversed_slots = torch.from_numpy(columns[0].numpy()).view(rows, slots).flip(1).contiguous().sum(1)
        assert not torch.equal(reversed_slots, stacked[:, 0])


@needs_drjit
def test_a_dark_materials_losses_keep_float32_precision(zoo):
    """Albedos of 0.0025 and a target 1.5x the model: each sample's log-L1 is ~1e-4 of values ~1e-4, which
    log(1 + x) in float32 would get 10 % wrong (x's digits below 1's ulp); log1p keeps them, so each
    sample's loss is within 4x the float32 torch kernel's relative error of float64's, plus a few ulps."""
    from neuenh.specialize import SpecializedBRDF

    model = get_model("ggx", state="00000000000", seed=0)
    space = RowSpace(model)
    table = MaterialTable(model.specs, zoo.names, model.latent_dim)
    with torch.no_grad():
        table.raw["rho_d"].fill_(-6.0)
        table.raw["rho_s"].fill_(-6.0)
    x = space.from_table(table)[:1]
    wi, wo, _, valid = padded(zoo)
    f_r = (SpecializedBRDF(model, table.as_params(0))(wi[0], wo[0]) * 1.5)[None]
    layout = layout_rows(wi, wo, f_r, torch.tensor([0]), valid[:1], torch.zeros_like(valid[:1]))
    double = copy.deepcopy(model).double()
    exact = RowKernel(double, RowSpace(double))(x.double(), layout_rows(
        wi.double(), wo.double(), f_r.double(), torch.tensor([0]), valid[:1], torch.zeros_like(valid[:1])))
    relative = lambda r: ((r.per_sample - exact.per_sample).abs() / exact.per_sample.abs())[valid[:1]].max()
    assert float(exact.per_sample[valid[:1]].median()) < 1e-3
    eps = torch.finfo(torch.float32).eps
    assert relative(JitRowKernel(model, space)(x, layout)) <= 4 * relative(RowKernel(model, space)(x, layout)) + 8 * eps


@needs_drjit
def test_the_jit_kernel_is_finite_at_grazing_below_horizon_and_tiny_roughness():
    """The stability cases of the torch kernel's test: 89.99 degrees, below either horizon, at the
    horizon, roughness at its lower bound, a huge target: finite losses and gradients."""
    model = small_ggx(PAPER_STATE, seed=0)
    space = RowSpace(model)
    graze = torch.tensor([0.99999998, 0.0, 2e-4])
    cases = [(graze, graze * torch.tensor([-1.0, 1.0, 1.0])), (torch.tensor([0.0, 0.6, -0.8]), torch.tensor([0.0, 0.0, 1.0])),
             (torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.6, 0.0, -0.8])), (torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0])),
             (torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.0, 0.0, 1.0]))]
    wi = torch.nn.functional.normalize(torch.stack([c[0] for c in cases]).float(), dim=1)
    wo = torch.nn.functional.normalize(torch.stack([c[1] for c in cases]).float(), dim=1)
    f_r = torch.tensor([[1e4, 0.0, 1.0]]).expand(len(wi), 3)
    table = MaterialTable(model.specs, ["m"], model.latent_dim)
    with torch.no_grad():
        for name in ("alpha_x", "alpha_y"):
            table.raw[name].fill_(-17.0)
    every = torch.ones(1, len(wi), dtype=torch.bool)
    layout = layout_rows(wi[None], wo[None], f_r[None], torch.tensor([0]), every, every)
    out = JitRowKernel(model, space)(space.from_table(table), layout, surrogate_eps=1e-3)
    assert torch.isfinite(out.objective).all() and torch.isfinite(out.val).all() and torch.isfinite(out.grad).all()


@needs_drjit
def test_a_protocols_kernel_names_the_jit_kernel_where_a_sample_reads_few_correction_factors():
    """The jit kernel gathers each correction factor per sample: up to ``JIT_FACTOR_READS`` of them it is
    the faster, above it the torch kernel fits the rows."""
    model = get_model("ggx", state="00010001000", seed=3)
    assert isinstance(row_kernel(model, RowSpace(model), "jit"), JitRowKernel)
    assert type(row_kernel(model, RowSpace(model), "torch")) is RowKernel
    out, inp = model.neural["F"].layers[3].weight.shape
    last = RowSpace(model, [LayerCorrection("F", 3)])  # its weights and biases
    assert JitRowKernel(model, last).factor_reads == out * inp + out
    assert isinstance(row_kernel(model, last, "jit"), JitRowKernel)
    first = model.neural["F"].layers[0].weight.shape[0]
    folded = RowSpace(model, [LayerCorrection("F", 0, 2)])  # U, V's columns of the 6 directions; the bias is per row
    assert JitRowKernel(model, folded).factor_reads == first * 2 + 2 * 6
    out, inp = model.neural["F"].layers[1].weight.shape
    rank = JIT_FACTOR_READS // (out + inp) + 1  # a rank-r delta reads U (out, r), V (r, in) and the bias
    many = RowSpace(model, [LayerCorrection("F", 1, rank)])
    assert JitRowKernel(model, many).factor_reads == rank * (out + inp) + out > JIT_FACTOR_READS
    assert type(row_kernel(model, many, "jit")) is RowKernel
    with pytest.raises(ValueError, match="kernel must be one of torch, jit"):
        row_kernel(model, RowSpace(model), "cuda")
    for protocol in (PlainLBFGS, LatentAdam, Adaptive):
        with pytest.raises(ValueError, match="invalid"):
            protocol(kernel="cuda")


@needs_drjit
def test_fit_threads_reach_drjit_only_once_a_fit_takes_it():
    """``set_fit_threads``: torch's threads at once; Dr.Jit's without importing it (a torch fit's
    process never loads it), applied when the jit kernel first initialises Dr.Jit."""
    import subprocess
    import sys

    script = ("import sys, torch; from neuenh.fit.jit import available, set_fit_threads; set_fit_threads(1); "
              "print(torch.get_num_threads(), 'drjit' in sys.modules); available(); import drjit as dr; "
              "print(dr.thread_count())")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.split() == ["1", "False", "1"], out.stdout + out.stderr


def test_without_drjit_the_jit_kernel_is_an_error_to_ask_for_and_torch_where_it_is_a_setting(monkeypatch):
    """A user's ``--kernel jit`` on a machine without Dr.Jit says what to install; a protocol's setting —
    the latent fit's default among them — falls back to the torch kernel (a bundle's fits run wherever it
    is loaded)."""
    import neuenh.fit.jit as jit

    monkeypatch.setitem(jit._STATE, "ok", False)
    with pytest.raises(ValueError, match="needs Dr.Jit's LLVM backend: pip install 'neuenh\\[export\\]'"):
        FitOptions(kernel="jit")
    model = get_model("ggx", state="00010001000", seed=3)
    assert type(row_kernel(model, RowSpace(model), "jit")) is RowKernel
    assert FitOptions(kernel="torch", capacity="latent").protocol_for(model).kernel == "torch"
    assert FitOptions(capacity="latent").protocol_for(model).kernel == "auto"  # no error: a default, not an ask
    assert type(row_kernel(model, RowSpace(model), "auto", work=10**9)) is RowKernel


def test_each_protocols_default_kernel_and_narrowing_are_the_ones_rule_m_chose():
    """Rule m (docs/BENCHMARKS.md, "Stop 68"): the latent fit takes the jit kernel ("auto": for fits of at
    least ``JIT_MIN_WORK``, below which a model's compile costs more than its fits save) and narrows its
    starts at half the epochs; the plain and adaptive fits keep torch, the adaptive fit's latent stage its
    narrowing after a quarter, and a search's fit score torch's kernel (inside a candidate's CPU share).
    The plain fit keeps its one warm-up start (rules t-v, "Stop 73", failed). Needs no Dr.Jit: these are
    the protocols' settings, not their kernels."""
    from neuenh.selection import score_protocol
    from neuenh.train import FitScoreConfig

    model, plain = get_model("ggx", state="00010001000", seed=3), get_model("ggx")
    latent = FitOptions(capacity="latent").protocol_for(model)
    assert (latent.kernel, latent.narrow_at) == ("auto", 0.5) and latent == LatentAdam()
    assert FitOptions(capacity="latent", kernel="torch").protocol_for(model).kernel == "torch"
    adaptive = FitOptions(capacity="auto").protocol_for(model)
    assert adaptive.kernel == "torch" == FitOptions().protocol_for(plain).kernel
    assert FitOptions().protocol_for(plain).warmup_lrs == (0.05,)
    assert (adaptive.latent_protocol.kernel, adaptive.latent_protocol.narrow_at) == ("torch", 0.25)
    assert Adaptive(kernel="jit").latent_protocol.kernel == "jit"
    assert Adaptive(latent_narrow_at=0.5).latent_protocol.narrow_at == 0.5  # rule n's arm (failed: Stop 68)
    assert Adaptive(latent_kernel="auto").latent_protocol.kernel == "auto"  # the latent stage's own kernel (rule o)
    assert Adaptive(kernel="jit", latent_kernel="torch").latent_protocol.kernel == "torch"
    assert adaptive.latent_protocol.coarse_slots is None  # every sample for every start
    assert Adaptive(latent_coarse_slots=3000).latent_protocol.coarse_slots == 3000
    for invalid in ({"latent_narrow_at": 1.0}, {"latent_kernel": "fast"}, {"latent_coarse_slots": 0}):
        with pytest.raises(ValueError, match="invalid adaptive protocol"):
            Adaptive(**invalid)
    scored = score_protocol(model, FitScoreConfig())
    assert isinstance(scored, LatentAdam) and scored.kernel == "torch"


@needs_drjit
def test_the_auto_kernel_is_jit_from_a_fits_work_of_jit_min_work_on(monkeypatch):
    """"auto" by the fit's measurement-epochs: torch below ``JIT_MIN_WORK`` (a test's or a quick look's fit,
    where a compile would cost more than it saves), jit from it on, torch without a work to go by."""
    model = MODELS["F and S*D*F"]()
    space = RowSpace(model)
    assert type(row_kernel(model, space, "auto", work=JIT_MIN_WORK - 1)) is RowKernel
    assert isinstance(row_kernel(model, space, "auto", work=JIT_MIN_WORK), JitRowKernel)
    assert type(row_kernel(model, space, "auto")) is RowKernel
    samples = sample_materials(synthetic_zoo(1, seed=5), 700, seed=1)
    steps, original = [], JitRowKernel.__call__
    monkeypatch.setattr(JitRowKernel, "__call__", lambda self, *a, **k: steps.append(1) or original(self, *a, **k))
    fit_materials(model, samples, LatentAdam(epochs=JIT_MIN_WORK // 700 - 1, screened=0))
    assert not steps, "a fit under JIT_MIN_WORK ran jit steps"
    fit_materials(model, samples, LatentAdam(epochs=JIT_MIN_WORK // 700 + 1, screened=0))
    assert steps, "a fit of JIT_MIN_WORK ran no jit step"


@needs_drjit
@pytest.mark.parametrize("protocol", [
    LatentAdam(epochs=9),
    Adaptive(capacities=("latent", "last-layer"), latent_epochs=6, correction_epochs=4, priors=(1e-2,), folds=2),
], ids=["latent", "adaptive"])
def test_an_adam_fit_with_the_jit_kernel_ends_where_the_torch_fit_ends(protocol, zoo):
    """The same protocol, kernel "jit" against "torch", from the same starts: the same choices and fit
    losses within 1 % (a few Adam steps: the kernels' rounding has not yet moved an end point, which it
    does after enough steps, as a fit's seed does: docs/BENCHMARKS.md, "Stop 64"; L-BFGS's line searches
    amplify it from the first steps, so the plain fit is checked by what it recovers: test_fit.py)."""
    import dataclasses

    model = MODELS["F and S*D*F"]()
    torch_fit = fit_materials(model, zoo, dataclasses.replace(protocol, kernel="torch"))
    jit_fit = fit_materials(model, zoo, dataclasses.replace(protocol, kernel="jit"))
    assert jit_fit.losses == pytest.approx(torch_fit.losses, rel=1e-2)
    capacities = lambda fit: [fit.materials.as_params(i).capacity for i in range(len(zoo.names))]
    assert capacities(jit_fit) == capacities(torch_fit)
