"""Image and sample metrics against independent references.

ΔE_ITP is checked against a numpy implementation written here from the standards (primaries ->
BT.709 to BT.2020 matrix, BT.2100 LMS and ICtCp matrices, SMPTE ST 2084 PQ constants, BT.2124
formula) and against exact values for grey levels; SSIM against a direct skimage call with the
documented tone mapping written out by hand, and by its properties; log-L1 against the formula.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from neuenh.render import metrics
from neuenh.train import log_l1 as train_log_l1

# ---------------------------------------------------------------- independent ΔE_ITP reference

D65 = (0.3127, 0.3290)
BT709 = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
BT2020 = ((0.708, 0.292), (0.170, 0.797), (0.131, 0.046))
LMS = np.array([[1688, 2146, 262], [683, 2951, 462], [99, 309, 3688]]) / 4096  # BT.2100 table 6
ICTCP = np.array([[2048, 2048, 0], [6610, -13613, 7003], [17933, -17390, -543]]) / 4096
M1, M2 = 2610 / 16384, 2523 / 4096 * 128  # SMPTE ST 2084
C1, C2, C3 = 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32


def xy_to_xyz(x: float, y: float) -> np.ndarray:
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


def rgb_to_xyz(primaries) -> np.ndarray:
    """Normalised primary matrix (SMPTE RP 177): columns are the primaries scaled to sum to white."""
    p = np.stack([xy_to_xyz(*xy) for xy in primaries], axis=1)
    return p * np.linalg.solve(p, xy_to_xyz(*D65))


BT709_TO_BT2020 = np.linalg.solve(rgb_to_xyz(BT2020), rgb_to_xyz(BT709))


def pq(nits: np.ndarray) -> np.ndarray:
    y = (nits / 10000.0) ** M1
    return ((C1 + C2 * y) / (1.0 + C3 * y)) ** M2


def reference_ictcp(rgb709: np.ndarray, peak_nits: float) -> np.ndarray:
    return pq(rgb709 @ BT709_TO_BT2020.T @ LMS.T * peak_nits) @ ICTCP.T


def reference_delta_e_itp(a: np.ndarray, b: np.ndarray, peak_nits: float) -> np.ndarray:
    d = reference_ictcp(a, peak_nits) - reference_ictcp(b, peak_nits)
    return 720.0 * np.sqrt(d[..., 0] ** 2 + (0.5 * d[..., 1]) ** 2 + d[..., 2] ** 2)


def test_bt709_to_bt2020_matrix_matches_bt2087() -> None:
    """The test's own derivation agrees with the 4-digit matrix published in ITU-R BT.2087."""
    published = [[0.6274, 0.3293, 0.0433], [0.0691, 0.9195, 0.0114], [0.0164, 0.0880, 0.8956]]
    np.testing.assert_allclose(BT709_TO_BT2020, published, atol=6e-5)


@pytest.mark.parametrize("peak_nits", [100.0, 203.0, 1000.0])
def test_delta_e_itp_matches_the_standard_formulas(peak_nits: float) -> None:
    rng = np.random.default_rng(0)
    a = rng.random((500, 3)) * rng.choice([0.01, 1.0, 5.0], size=(500, 1))
    b = a * rng.normal(1.0, 0.05, a.shape).clip(0.5) + rng.random(a.shape) * 1e-3
    expected = reference_delta_e_itp(a, b, peak_nits)
    np.testing.assert_allclose(metrics.delta_e_itp_map(a, b, peak_nits), expected, rtol=1e-9, atol=1e-12)
    assert metrics.delta_e_itp(a, b, peak_nits=peak_nits) == pytest.approx(expected.mean(), rel=1e-9)
    np.testing.assert_allclose(metrics.ictcp(a, peak_nits), reference_ictcp(a, peak_nits), rtol=1e-9, atol=1e-12)


def test_delta_e_itp_exact_values_for_greys() -> None:
    """Greys have Ct = Cp = 0 and I = PQ(luminance): black vs 10 000 cd/m² is 720·(1 − c1^m2)."""
    black, peak = np.zeros(3), np.full(3, 100.0)  # 100 × 100 cd/m² = the top of the PQ range
    assert metrics.delta_e_itp(black, peak) == pytest.approx(720.0 * (1.0 - C1**M2), rel=1e-12)
    # 100 cd/m² white encodes to PQ ≈ 0.5081 (the familiar "100 nits is half the PQ signal")
    np.testing.assert_allclose(metrics.ictcp(np.ones(3)), [0.50808, 0.0, 0.0], atol=1e-5)
    # a pure luminance step between two greys is 720·|ΔI|, whatever the grey
    a, b = np.full(3, 0.5), np.full(3, 0.55)
    assert metrics.delta_e_itp(a, b) == pytest.approx(720.0 * abs(pq(np.array(55.0)) - pq(np.array(50.0))), rel=1e-12)


def test_delta_e_itp_mask_selects_pixels_and_peak_scales() -> None:
    rng = np.random.default_rng(1)
    a = rng.random((8, 9, 3))
    b = a.copy()
    b[:4] *= 1.2
    mask = np.zeros((8, 9), dtype=bool)
    mask[4:] = True
    assert metrics.delta_e_itp(a, b, mask=mask) == 0.0
    assert metrics.delta_e_itp(a, b, mask=~mask) > 0.0
    assert metrics.delta_e_itp(a, b, peak_nits=1000.0) != metrics.delta_e_itp(a, b)
    # negatives are clipped to 0 before encoding
    assert metrics.delta_e_itp(np.array([[-1.0, 0.2, 0.3]]), np.array([[0.0, 0.2, 0.3]])) == 0.0


# ----------------------------------------------------------------------------- identical images


def image(seed: int = 0, shape=(48, 64)) -> np.ndarray:
    """A smooth HDR image with highlights above 1 and a dark region."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]] / max(shape)
    base = np.stack([np.sin(6 * x) ** 2, np.cos(4 * y) ** 2, x * y], axis=-1)
    return base * 2.0 + 0.05 * rng.random((*shape, 3))


def test_identical_images() -> None:
    a = image()
    assert metrics.ssim(a, a.copy()) == pytest.approx(1.0, abs=1e-12)
    assert metrics.delta_e_itp(a, a.copy()) == 0.0
    assert metrics.ssim(torch.from_numpy(a), torch.from_numpy(a)) == pytest.approx(1.0, abs=1e-12)


# ------------------------------------------------------------------------------------------- SSIM


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 written out."""
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


@pytest.mark.parametrize("exposure", [0.0, -1.5])
def test_ssim_is_skimage_on_the_documented_tone_mapping(exposure: float) -> None:
    a = image(0)
    b = a * 1.1 + 0.1 * np.random.default_rng(2).normal(size=a.shape)  # some negatives too
    scale = 2.0**exposure
    ta = np.clip(srgb_encode(np.maximum(a * scale, 0)), 0, 1)
    tb = np.clip(srgb_encode(np.maximum(b * scale, 0)), 0, 1)
    expected = structural_similarity(
        ta, tb, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
    )
    assert metrics.ssim(a, b, exposure=exposure) == pytest.approx(expected, abs=1e-12)
    np.testing.assert_allclose(metrics.tone_map(a, exposure), ta, atol=1e-12)


def test_ssim_decreases_as_noise_grows() -> None:
    a = image(0)
    noise = np.random.default_rng(3).normal(size=a.shape)
    values = [metrics.ssim(a, a + sigma * noise) for sigma in (0.0, 0.01, 0.03, 0.1, 0.3)]
    assert values[0] == pytest.approx(1.0)
    assert all(later < earlier for earlier, later in zip(values, values[1:])), values


def test_ssim_of_a_constant_offset_is_below_one() -> None:
    a = image(0) * 0.5
    assert metrics.ssim(a, a + 0.2) < 1.0


def test_masked_ssim_ignores_pixels_outside_the_mask_exactly() -> None:
    a, b = image(0), image(1)
    mask = np.zeros(a.shape[:2], dtype=bool)
    mask[10:30, 15:50] = True
    value = metrics.ssim(a, b, mask=mask)
    rng = np.random.default_rng(4)
    a2, b2 = a.copy(), b.copy()
    a2[~mask] = rng.random((int((~mask).sum()), 3)) * 5
    b2[~mask] = 0.0
    assert metrics.ssim(a2, b2, mask=mask) == value
    # changes inside the mask do count
    b3 = b.copy()
    b3[mask] *= 1.5
    assert metrics.ssim(a, b3, mask=mask) != value


def test_all_true_mask_equals_unmasked() -> None:
    a, b = image(0), image(1)
    full = np.ones(a.shape[:2], dtype=bool)
    assert metrics.ssim(a, b, mask=full) == pytest.approx(metrics.ssim(a, b), abs=1e-12)
    assert metrics.delta_e_itp(a, b, mask=full) == pytest.approx(metrics.delta_e_itp(a, b), rel=1e-12)


# ---------------------------------------------------------------------------------------- log-L1


def test_log_l1_is_the_training_loss_on_numpy_inputs() -> None:
    rng = np.random.default_rng(5)
    n = 200
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    f_true = rng.random((n, 3)) * 3
    f_pred = f_true + rng.normal(0, 0.5, (n, 3))  # includes negative predictions
    cos = np.maximum(wi[:, 2:3], 0)
    by_formula = np.abs(np.log1p(f_true * cos) - np.sign(f_pred * cos) * np.log1p(np.abs(f_pred * cos))).mean()
    by_train = float(train_log_l1(torch.from_numpy(f_pred), torch.from_numpy(f_true), torch.from_numpy(wi)).mean())
    for third in (wi, wi[:, 2], wi[:, 2:3], torch.from_numpy(wi)):
        assert metrics.log_l1(f_true, f_pred, third) == pytest.approx(by_formula, rel=1e-12)
    assert by_train == pytest.approx(by_formula, rel=1e-12)
    assert metrics.log_l1(f_true, f_true, wi) == 0.0


# ---------------------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda a: metrics.ssim(a, a[:, :-1]), "shape mismatch"),
        (lambda a: metrics.delta_e_itp(a, a[:-1]), "shape mismatch"),
        (lambda a: metrics.ssim(a, np.where(a > 1.5, np.nan, a)), "non-finite"),
        (lambda a: metrics.delta_e_itp(np.where(a > 1.5, np.inf, a), a), "non-finite"),
        (lambda a: metrics.ssim(a, a, mask=np.zeros(a.shape[:2], bool)), "empty mask"),
        (lambda a: metrics.delta_e_itp(a, a, mask=np.zeros(a.shape[:2], bool)), "empty mask"),
        (lambda a: metrics.ssim(a, a, mask=np.eye(48, 64, dtype=bool)[:5]), "mask shape"),
        (lambda a: metrics.ssim(a, a, mask=np.ones(a.shape[:2])), "boolean"),
        (lambda a: metrics.ssim(a[:8, :8], a[:8, :8]), "at least 11x11"),
        (lambda a: metrics.ssim(a[..., 0], a[..., 0]), "(H, W, 3)"),
        (lambda a: metrics.delta_e_itp(a, a, peak_nits=0.0), "peak_nits"),
        (lambda a: metrics.log_l1(a[0], a[1, :-1], np.ones(64)), "shape mismatch"),
        (lambda a: metrics.log_l1(a[0], a[0] * np.nan, np.ones(64)), "non-finite"),
        (lambda a: metrics.log_l1(a[0], a[0], np.ones(63)), "cos_i"),
        (lambda a: metrics.log_l1(a[0, :0], a[0, :0], np.ones(0)), "no samples"),
    ],
)
def test_invalid_inputs_are_refused_with_a_named_problem(call, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        call(image(0))
