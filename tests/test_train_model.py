"""U-Net, evaluation metrics and the training module's on-device batch making."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from lightning import Trainer

from rawaug.train.metrics import ResultsTable, centre_crop, corrected, evaluate, fit_scale, psnr, ssim
from rawaug.train.module import DenoiseModule
from rawaug.train.unet import UNet


# ---------------------------------------------------------------- U-Net
def test_unet_paper_widths_and_shapes():
    net = UNet()  # paper: 4 -> 32, 64, 128, 256, 512 -> 4
    widths = [block[0].out_channels for block in net.down]
    assert widths == [32, 64, 128, 256, 512]
    assert net.down[0][0].in_channels == 4 and net.head.out_channels == 4
    assert all(m.negative_slope == 0.2 for m in net.modules() if isinstance(m, torch.nn.LeakyReLU))
    small = UNet(base_channels=4)
    for h, w in ((32, 32), (20, 36), (17, 9)):  # any size: padded inside, cropped back
        assert small(torch.rand(2, 4, h, w)).shape == (2, 4, h, w)


def test_unet_residual_and_bad_args():
    net = UNet(base_channels=2, residual=True)
    for p in net.head.parameters():
        torch.nn.init.zeros_(p)
    x = torch.rand(1, 4, 16, 16)
    assert torch.equal(net(x), x)
    with pytest.raises(ValueError, match="base_channels"):
        UNet(base_channels=0)
    with pytest.raises(ValueError, match="depth"):
        UNet(depth=1)
    with pytest.raises(ValueError, match="shape"):
        UNet(base_channels=2)(torch.rand(4, 8, 8))


# ---------------------------------------------------------------- metrics
def test_least_squares_scale_and_psnr_against_hand_computation():
    out = torch.tensor([0.1, 0.2]).view(1, 1, 1, 2)
    tgt = torch.tensor([0.2, 0.3]).view(1, 1, 1, 2)
    # a = <o,t>/<o,o> = (0.02 + 0.06) / (0.01 + 0.04) = 1.6; corrected = (0.16, 0.32)
    assert fit_scale(out, tgt).item() == pytest.approx(1.6, rel=1e-6)
    fixed = corrected(out, tgt)
    np.testing.assert_allclose(fixed.flatten().numpy(), [0.16, 0.32], rtol=1e-6)
    # mse = (0.04^2 + 0.02^2) / 2 = 0.001 -> 30 dB
    assert psnr(fixed, tgt).item() == pytest.approx(30.0, abs=1e-4)
    assert math.isinf(psnr(tgt, tgt).item())


def test_scale_correction_undoes_a_global_gain():
    torch.manual_seed(0)
    tgt = torch.rand(2, 4, 32, 32) * 0.8
    got = evaluate(tgt * 0.7, tgt)
    assert torch.all(got["psnr"] > 100) and torch.allclose(got["ssim"], torch.ones(2), atol=1e-5)


def test_ssim_matches_torchmetrics_per_channel_average():
    tm = pytest.importorskip("torchmetrics.functional.image")
    torch.manual_seed(1)
    tgt = torch.rand(2, 4, 48, 40)
    out = (tgt + 0.1 * torch.randn_like(tgt)).clamp(0, 1)
    ours = ssim(out, tgt)
    ref = torch.stack([
        torch.stack([tm.structural_similarity_index_measure(out[b:b + 1, c:c + 1], tgt[b:b + 1, c:c + 1], data_range=1.0) for c in range(4)]).mean()
        for b in range(2)])
    torch.testing.assert_close(ours, ref, atol=2e-3, rtol=0)
    assert torch.all(ours < 0.95)  # the noise is seen
    with pytest.raises(ValueError, match="11x11"):
        ssim(torch.rand(1, 4, 8, 8), torch.rand(1, 4, 8, 8))
    with pytest.raises(ValueError, match="shape"):
        psnr(torch.rand(1, 4, 8, 8), torch.rand(1, 4, 8, 6))


def test_centre_crop():
    x = torch.arange(36.0).view(1, 1, 6, 6)
    assert centre_crop(x, 2).flatten().tolist() == [14.0, 15.0, 20.0, 21.0]
    assert centre_crop(x, None) is x and centre_crop(x, 10).shape == x.shape


def test_results_table_groups_and_writes_atomically(tmp_path):
    table = ResultsTable()
    table.add("SonyA7S2", 100.0, "a", 30.0, 0.5, 40.0, 0.9)
    table.add("SonyA7S2", 100.0, "b", 32.0, 0.7, 42.0, 0.8)
    table.add("SonyA7S2", 200.0, "c", 25.0, 0.4, 35.0, 0.7)
    rows = table.summary()
    assert [(r["ratio"], r["images"], r["psnr_db"], r["psnr_noisy_db"]) for r in rows] == [(100, 2, 41.0, 31.0), (200, 1, 35.0, 25.0)]
    assert rows[0]["ssim"] == pytest.approx(0.85)
    csv_path, md_path = table.write(tmp_path / "out", "test_results")
    assert csv_path.read_text().splitlines()[1] == "SonyA7S2,100,2,31.0000,0.6000,41.0000,0.8500"
    assert "| SonyA7S2 | x200 | 1 | 25.00 | 0.4000 | 35.00 | 0.7000 |" in md_path.read_text()
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["test_results.csv", "test_results.md"]


# ---------------------------------------------------------------- module
def _module(**kw):
    return DenoiseModule(**{"base_channels": 2, "crop_size": 16, **kw})


def test_training_pair_is_cropped_noisy_and_replayable():
    torch.manual_seed(0)
    m = _module(iso=3200, ratio=100)
    clean = torch.rand(3, 4, 40, 40) * 0.5 + 0.2
    a = m.make_training_pair({"target": clean}, seed=5)
    b = m.make_training_pair({"target": clean}, seed=5)
    c = m.make_training_pair({"target": clean}, seed=6)
    assert a["input"].shape == a["target"].shape == (3, 4, 16, 16)
    assert torch.equal(a["input"], b["input"]) and torch.equal(a["target"], b["target"])
    assert not torch.equal(a["input"], c["input"])
    assert a["input"].min() >= 0 and a["input"].max() <= 1  # clip_input
    # the target crop is one of the 8 flips/rotations of a window of the clean frame
    t = a["target"][0]
    found = False
    for k in range(4):
        for flip in (False, True):
            v = torch.rot90(t, -k, (-2, -1))
            v = v.flip(-1) if flip else v
            for i in range(25):
                for j in range(25):
                    found |= any(torch.equal(clean[n, :, i:i + 16, j:j + 16], v) for n in range(3))
    assert found
    # noise at ISO 3200 x100 on signal ~0.45: per-pixel std well above zero, mean kept
    resid = a["input"] - a["target"]
    assert 0.02 < resid.std() < 0.5 and abs(resid.mean()) < 4 * resid.std() / math.sqrt(resid.numel()) + 0.01


def test_real_pairs_get_the_same_geometry_and_no_synthetic_noise():
    m = _module()
    clean = torch.rand(2, 4, 32, 32)
    noisy = clean * 0.5
    pair = m.make_training_pair({"target": clean, "input": noisy}, seed=1)
    torch.testing.assert_close(pair["input"], pair["target"] * 0.5)


def test_crop_larger_than_frame_is_an_error():
    with pytest.raises(ValueError, match="crop_size"):
        _module().make_training_pair({"target": torch.rand(1, 4, 8, 8)}, seed=0)
    with pytest.raises(ValueError, match="crop_size"):
        DenoiseModule(base_channels=2, crop_size=8)  # depth 5 needs >= 16


def test_eval_noise_is_fixed_per_frame_name():
    m = _module(eval_iso=1600, eval_ratio=100, eval_crop=24)
    clean = torch.full((1, 4, 40, 40), 0.3)
    n1, t1 = m.eval_input({"target": clean, "name": ["scene-a"]})
    n2, _ = m.eval_input({"target": clean, "name": ["scene-a"]})
    n3, _ = m.eval_input({"target": clean, "name": ["scene-b"]})
    assert n1.shape == t1.shape == (1, 4, 24, 24)
    assert torch.equal(n1, n2) and not torch.equal(n1, n3)
    # SonyA7S2 at ISO 1600 x100: shot noise alone gives std >= sqrt(0.3 * span / ratio / K) * K * ratio / span
    k = m.eval_noise.profile.k_at_iso(1600)
    span = m.eval_noise.profile.span_dn
    shot = math.sqrt(0.3 * span / 100 / k) * k * 100 / span
    assert n1.std().item() > 0.8 * shot


def test_learning_rate_schedule_follows_the_paper():
    m = _module(lr=1e-4)
    assert m.lr_at_epoch(150) == pytest.approx(1e-4)  # no trainer: constant
    m.trainer = Trainer(max_epochs=200, logger=False, enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False)
    lrs = [m.lr_at_epoch(e) for e in range(200)]
    assert lrs[0] == lrs[99] == pytest.approx(1e-4)
    assert lrs[100] == lrs[179] == pytest.approx(5e-5)
    assert lrs[180] == lrs[199] == pytest.approx(1e-5)
    m.trainer = Trainer(max_epochs=10, logger=False, enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False)
    assert [m.lr_at_epoch(e) / 1e-4 for e in (4, 5, 8, 9)] == pytest.approx([1, 0.5, 0.5, 0.1])
    with pytest.raises(ValueError, match="lr_milestones"):
        _module(lr_milestones=[0.9, 0.5])


def test_learning_rate_schedule_with_a_step_budget():
    # max_steps without max_epochs: the milestones are fractions of the steps (before, the rate
    # stayed constant, and at lr 1e-3 CPU-scale runs spiked and ended wherever they were)
    m = _module(lr=1e-3)
    m.trainer = Trainer(max_steps=1000, logger=False, enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False)
    assert m._step_budget()
    assert [m.lr_at_step(s) / 1e-3 for s in (0, 499, 500, 899, 900, 999)] == pytest.approx([1, 1, 0.5, 0.5, 0.1, 0.1])
    m.trainer = Trainer(max_epochs=10, max_steps=1000, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False)
    assert not m._step_budget()  # an epoch budget wins: the epoch schedule applies


def test_the_step_schedule_reaches_the_optimizer_in_a_fit():
    from lightning.pytorch.callbacks import Callback

    from rawaug.train import CleanFolder, RawDenoiseData

    seen = []

    class Record(Callback):
        def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
            seen.append(trainer.optimizers[0].param_groups[0]["lr"])

    m = _module(lr=1e-3, lr_milestones=[0.5], lr_factors=[0.1], base_channels=2, crop_size=16)
    data = RawDenoiseData(train=CleanFolder(split="train", repeat=1), batch_size=1)
    Trainer(max_steps=4, logger=False, enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
            limit_val_batches=0, callbacks=[Record()], accelerator="cpu").fit(m, datamodule=data)
    assert seen == pytest.approx([1e-3, 1e-3, 1e-4, 1e-4])


def test_exposure_gives_the_profiles_dark_signal_in_training_and_evaluation():
    # SonyA7S2 + Dark (10 e-/s, no DSNU) at K = 1, ratio 1: 2 s add 20 e- (Poisson, with the
    # read noise), none without an exposure; training and evaluation noise alike
    dark = {"Dark": {"seed": 3, "k": [1.0], "rate_e_per_s": [10.0], "dsnu": [0.0]}}
    clean = torch.zeros(4, 4, 32, 32)
    means = {}
    for exposure in (None, 2.0):
        m = DenoiseModule(base_channels=2, crop_size=32, profile_effects=dark, k=1.0, ratio=1.0, eval_k=1.0, eval_ratio=1.0,
                          exposure_s=exposure, clip_input=False, flip=False, rotate=False)
        span = m.noise.profile.span_dn
        train = m.make_training_pair({"target": clean}, seed=1)["input"] * span
        evaluated, _ = m.eval_input({"target": clean, "name": ["a", "b", "c", "d"]})
        means[exposure] = (float(train.mean()), float(evaluated.mean() * span))
        sd = float(train.std()) / math.sqrt(train.numel())  # DN, standard error of the mean
        expected = 0.0 if exposure is None else 20.0
        for got in means[exposure]:
            assert abs(got - expected) < 5 * sd, (exposure, means, sd)
