"""Every noise model through the same contract checks (kornia conventions, replay, safety)."""
import pickle

import kornia.augmentation as K
import pytest
import torch

from rawaug import PAPER_MODELS, RawNoiseAugment

MODELS = list(PAPER_MODELS) + ["G*+P*+R+U+C"]
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def clean(batch=2, size=16, dtype=torch.float32, device="cpu"):
    return (torch.rand(batch, 4, size, size, generator=torch.Generator().manual_seed(0)) * 0.8).to(device, dtype)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("device", DEVICES)
def test_module_contract(model, device, samplers):
    aug = RawNoiseAugment("SonyA7S2", model=model)
    x = clean(device=device)
    before = x.clone()
    y = aug(x)
    assert torch.equal(x, before), "input was modified"
    assert y.shape == x.shape and y.dtype == x.dtype and y.device == x.device
    assert torch.isfinite(y).all()
    assert not torch.equal(y, x)
    params = aug._params
    assert torch.equal(aug(x, params=params), y), "replay is not bit-exact"
    assert not torch.equal(aug(x), y), "two calls drew the same noise"
    copy = pickle.loads(pickle.dumps(aug))
    assert torch.equal(copy(x, params=params), y), "a pickled copy does not replay"
    assert aug(x[:0]).shape == (0, 4, 16, 16)
    with pytest.raises(ValueError, match="2 samples"):
        aug(x[:1], params=params)


def test_params_hold_scalars_not_noise_maps():
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U+C")
    aug(clean(batch=3, size=64))
    from rawaug.engine.layout import N_COLUMNS

    assert set(aug._params) == {"seed", "batch_prob", "values"}
    assert aug._params["values"].shape == (3, N_COLUMNS)  # (B, P) scalars
    assert aug._params["seed"].numel() == 1 and aug._params["batch_prob"].numel() == 3


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float32, torch.float64])
def test_dtypes_are_kept_and_computed_in_float32_or_better(dtype):
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", ratio=1.0, fixed={"k": 1.0, "sigma_tl": 2.0, "lambda": 0.1, "sigma_r": 0.5})
    x = clean(dtype=dtype)
    y = aug(x)
    assert y.dtype == dtype
    if dtype in (torch.float16, torch.bfloat16):
        # half inputs are computed in float32 and rounded once at the end
        assert torch.equal(y, aug(x.float(), params=aug._params).to(dtype))


def test_p_zero_is_identity_and_p_gates_per_sample():
    x = clean(batch=32)
    assert torch.equal(RawNoiseAugment("SonyA7S2", p=0.0)(x), x)
    aug = RawNoiseAugment("SonyA7S2", p=0.5, generator=torch.Generator().manual_seed(1))
    y = aug(x)
    gate = aug._params["batch_prob"]
    unchanged = torch.tensor([torch.equal(y[i], x[i]) for i in range(32)])
    assert torch.equal(unchanged, ~gate)
    assert 0 < int(gate.sum()) < 32  # binomial(32, 1/2) at an end: P ~ 5e-10


def test_same_on_batch_shares_parameters_not_noise():
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U+C", same_on_batch=True)
    x = clean(batch=4).expand(4, 4, 16, 16).contiguous()
    x[:] = x[0]
    y = aug(x)
    for key, value in aug._params.items():
        if key != "seed":
            assert (value == value[0]).all(), key
    assert not torch.equal(y[0], y[1])


def test_keepdim_and_unbatched_input():
    x = clean(batch=1)[0]
    assert RawNoiseAugment("SonyA7S2", keepdim=True)(x).shape == (4, 16, 16)
    assert RawNoiseAugment("SonyA7S2")(x).shape == (1, 4, 16, 16)


def test_generator_makes_calls_reproducible():
    x = clean()
    a = RawNoiseAugment("SonyA7S2", generator=torch.Generator().manual_seed(7))(x)
    b = RawNoiseAugment("SonyA7S2", generator=torch.Generator().manual_seed(7))(x)
    c = RawNoiseAugment("SonyA7S2", generator=torch.Generator().manual_seed(8))(x)
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_ranks_seeded_alike_draw_different_noise(monkeypatch):
    x = clean()
    outs = []
    for rank in ("0", "1"):
        monkeypatch.setenv("RANK", rank)
        torch.manual_seed(123)  # what seed_everything does on every rank
        outs.append(RawNoiseAugment("SonyA7S2")(x))
    assert not torch.equal(outs[0], outs[1])
    monkeypatch.setenv("RANK", "1")
    torch.manual_seed(123)
    assert torch.equal(RawNoiseAugment("SonyA7S2")(x), outs[1])


def test_ablation_rows_share_their_common_noise():
    # Each effect has its own generator stream: G*+P*+R and G*+P*+R+U differ by U alone.
    x = clean()
    fixed = {"k": 1.0, "sigma_tl": 2.0, "lambda": 0.1, "sigma_r": 0.5, "ratio": 100.0}
    base = RawNoiseAugment("SonyA7S2", model="G*+P*+R", fixed=fixed)
    full = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=fixed)
    a = base(x, params=base.draw_parameters(2, "cpu", seed=5))
    b = full(x, params=full.draw_parameters(2, "cpu", seed=5))
    step = 1.0 * 100.0 / base.profile.span_dn  # U adds at most half a step, times the ratio
    assert (b - a).abs().max() <= step / 2 + 1e-6


def test_composes_with_geometric_augmentations_in_kornia():
    seq = K.AugmentationSequential(K.RandomHorizontalFlip(), K.RandomRotation(90.0, p=1.0), RawNoiseAugment("SonyA7S2"), data_keys=["input"])
    x = clean(batch=3)
    y = seq(x)
    assert y.shape == x.shape
    assert torch.equal(seq(x, params=seq._params), y)


def test_clip_white_option():
    x = torch.ones(2, 4, 16, 16)
    aug = RawNoiseAugment("SonyA7S2", ratio=1.0, clip_white=True)
    assert aug(x).max() <= 1.0
    assert RawNoiseAugment("SonyA7S2", ratio=1.0, fixed={"k": 6.0})(x).max() > 1.0


@pytest.mark.parametrize(
    "bad, error, words",
    [
        (torch.zeros(2, 4, 8, 8, dtype=torch.int64), TypeError, "floating-point"),
        (torch.zeros(2, 3, 8, 8), ValueError, "(2, 3, 8, 8)"),
        (torch.zeros(4, 8), ValueError, "(4, 8)"),
        (torch.tensor(float("nan")).expand(1, 4, 4, 4), ValueError, "NaN"),
        (torch.tensor(float("inf")).expand(1, 4, 4, 4), ValueError, "Inf"),
    ],
)
def test_bad_input_is_refused_with_a_clear_error(bad, error, words):
    with pytest.raises(error, match=words.replace("(", r"\(").replace(")", r"\)")):
        RawNoiseAugment("SonyA7S2")(bad)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"model": "G*+Q"}, "unknown noise component 'Q'"),
        ({"model": "G+G*"}, "both"),
        ({"ratio": (0, 10)}, "ratio"),
        ({"p": 1.5}, "p must be in"),
        ({"profile": "NoSuchCamera"}, "NoSuchCamera"),
    ],
)
def test_bad_arguments_name_the_value(kwargs, words):
    with pytest.raises(ValueError, match=words.replace("*", r"\*").replace("+", r"\+")):
        RawNoiseAugment(**{"profile": "SonyA7S2", **kwargs})


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cpu_and_cuda_agree_in_distribution():
    from scipy import stats

    fixed = {"k": 1.0, "sigma_tl": 2.0, "lambda": -0.1, "sigma_r": 0.5}
    outs = []
    for device in ("cpu", "cuda"):
        aug = RawNoiseAugment("SonyA7S2", ratio=1.0, fixed=fixed)
        outs.append(aug(torch.full((4, 4, 128, 128), 0.01, device=device)).cpu().numpy().ravel())
    assert stats.ks_2samp(outs[0][::7], outs[1][::7]).pvalue > 1e-3
