"""The real LightningCLI app (lightning_app/fit.py), in-process: every config with
``fast_dev_run`` on small crops, test tables, prediction, TensorBoard logging and exact resume."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile
from test_train_layouts import make_eld_tree, make_sid_tree

REPO = Path(__file__).resolve().parent.parent
CONFIGS = sorted((REPO / "configs").glob("*.yaml"))


def _fit_main():
    spec = importlib.util.spec_from_file_location("rawaug_fit_app", REPO / "lightning_app" / "fit.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main


_app_main = _fit_main()


def main(args):
    """fit.py's ``main(args)`` as a command line runs it: ``sys.argv`` holds only the program
    (pytest's own arguments there would make LightningCLI warn that both were given)."""
    saved = sys.argv
    sys.argv = [str(REPO / "lightning_app" / "fit.py")]
    try:
        return _app_main(args)
    finally:
        sys.argv = saved


@pytest.fixture(scope="module")
def trees(tmp_path_factory):
    base = tmp_path_factory.mktemp("trees")
    sid = make_sid_tree(base / "SID", size=64)
    eld = make_eld_tree(base / "ELD", scenes=(1,), size=64)
    profile = NoiseProfile.load("SonyA7S2").with_effect("BLE", {"k": [0.1, 6.0], "sigma_dn": [0.5, 2.0]})  # test values
    profile.save(base / "loop-profile.yaml")
    return {"sid": sid, "eld": eld, "profile": base / "loop-profile.yaml"}


def _small(out: Path) -> list[str]:
    return ["--model.base_channels", "4", "--model.crop_size", "16", "--model.results_dir", str(out / "results"),
            "--trainer.accelerator", "cpu", "--trainer.devices", "1", "--trainer.default_root_dir", str(out),
            "--trainer.logger.init_args.save_dir", str(out), "--data.init_args.num_workers", "0"]


def _layout_overrides(config: Path, trees, out: Path) -> list[str]:
    text = config.read_text()
    args = []
    if "rawaug.train.SIDSony" in text:
        args += ["--data.init_args.cache_dir", str(out / "cache")]
        args += [f"--data.init_args.{s}.init_args.root={trees['sid']}" for s in ("train", "val")]
    if "rawaug.train.ELD" in text:
        args += [f"--data.init_args.test.init_args.root={trees['eld']}", "--data.init_args.test.init_args.scenes=[1]"]
    elif "test:" in text:
        args += [f"--data.init_args.test.init_args.root={trees['sid']}"]
    if "SonyA7S2-loop" in text:
        args += ["--model.profile", str(trees["profile"])]
    return args


@pytest.mark.parametrize("config", CONFIGS, ids=[c.stem for c in CONFIGS])
def test_every_config_fits_with_fast_dev_run(config, trees, tmp_path):
    cli = main(["fit", "--config", str(config), "--trainer.fast_dev_run", "1", *_small(tmp_path), *_layout_overrides(config, trees, tmp_path)])
    metrics = cli.trainer.callback_metrics
    assert torch.isfinite(metrics["train/loss"])
    assert torch.isfinite(metrics["val/psnr"]) and torch.isfinite(metrics["val/psnr_noisy"])
    assert (tmp_path / "results" / "val_results.csv").is_file()


@pytest.mark.parametrize("name", ["sid_GsPsRU", "eld_GsPsRU"])
def test_test_command_writes_a_table_per_camera_and_ratio(name, trees, tmp_path):
    config = REPO / "configs" / f"{name}.yaml"
    main(["test", "--config", str(config), *_small(tmp_path), *_layout_overrides(config, trees, tmp_path)])
    lines = (tmp_path / "results" / "test_results.csv").read_text().splitlines()
    assert lines[0] == "camera,ratio,images,psnr_noisy_db,ssim_noisy,psnr_db,ssim"
    groups = [tuple(line.split(",")[:3]) for line in lines[1:]]
    if name.startswith("eld"):
        assert groups == [("SonyA7S2", "100", "3"), ("SonyA7S2", "200", "3")]
    else:  # Sony_test_list: 10/0.04 = 250 and 10/0.1 = 100
        assert groups == [("SonyA7S2", "100", "1"), ("SonyA7S2", "250", "1")]
    assert (tmp_path / "results" / "test_results.md").read_text().startswith("| camera | ratio |")


def test_validate_command_scores_the_held_out_scenes(tmp_path):
    cli = main(["validate", "--config", str(REPO / "configs" / "quickstart.yaml"), *_small(tmp_path), "--model.eval_crop", "64"])
    metrics = cli.trainer.callback_metrics
    assert 0 < metrics["val/psnr_noisy"] < 60 and torch.isfinite(metrics["val/psnr"])
    lines = (tmp_path / "results" / "val_results.csv").read_text().splitlines()
    assert lines[1].startswith("bundled-scenes,100,2,")


def test_predict_writes_denoised_frames(trees, tmp_path):
    noisy = tmp_path / "noisy"
    noisy.mkdir()
    np.save(noisy / "shot.npy", np.random.default_rng(0).integers(512, 700, (48, 64)).astype(np.uint16))
    args = ["predict", "--config", str(REPO / "configs" / "quickstart.yaml"), *_small(tmp_path),
            "--data.init_args.predict=rawaug.train.NoisyFolder", f"--data.init_args.predict.root={noisy}",
            "--data.init_args.predict.ratio=100", "--data.init_args.predict.cfa=RGGB",
            "--data.init_args.predict.black_level=512", "--data.init_args.predict.white_level=16383",
            "--trainer.callbacks+=rawaug.train.DenoisedWriter", f"--trainer.callbacks.output_dir={tmp_path / 'out'}"]
    main(args)
    out = np.load(tmp_path / "out" / "shot.npy")
    assert out.shape == (4, 24, 32) and out.dtype == np.float32 and 0 <= out.min() and out.max() <= 1


def _quick(out: Path, epochs: int, extra=()) -> list[str]:
    return ["fit", "--config", str(REPO / "configs" / "quickstart.yaml"), *_small(out), "--model.base_channels", "2",
            "--data.init_args.batch_size", "2", "--data.init_args.train.init_args.repeat", "1", "--model.eval_crop", "32",
            "--trainer.max_epochs", str(epochs), "--trainer.check_val_every_n_epoch", "1", "--trainer.log_every_n_steps", "1", *extra]


def _weights(ckpt: Path) -> dict:
    return torch.load(ckpt, map_location="cpu", weights_only=False)["state_dict"]


# Resuming run b's checkpoint into folder c on purpose: Lightning notes that c is another folder.
@pytest.mark.filterwarnings("ignore:The dirpath has changed")
def test_resume_from_checkpoint_is_exact_and_logs_to_tensorboard(tmp_path):
    straight = main(_quick(tmp_path / "a", 2))
    main(_quick(tmp_path / "b", 1))
    first = tmp_path / "b" / "version_0" / "checkpoints" / "last.ckpt"
    assert first.is_file()
    resumed = main(_quick(tmp_path / "c", 2, ["--ckpt_path", str(first)]))
    assert resumed.trainer.global_step == straight.trainer.global_step == 4
    a = _weights(tmp_path / "a" / "version_0" / "checkpoints" / "last.ckpt")
    c = _weights(tmp_path / "c" / "version_0" / "checkpoints" / "last.ckpt")
    one_epoch = _weights(first)
    assert a.keys() == c.keys()
    assert any(not torch.equal(a[k], one_epoch[k]) for k in a)  # the second epoch changed the weights
    for k in a:
        torch.testing.assert_close(c[k], a[k], rtol=0, atol=1e-7)
    # TensorBoard: scalars and the noisy/denoised/target grid
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(tmp_path / "a" / "version_0"), size_guidance={"images": 0})
    events.Reload()
    tags = events.Tags()
    assert {"train/loss", "val/psnr", "val/psnr_noisy", "val/ssim"} <= set(tags["scalars"])
    assert "val/noisy_denoised_target" in tags["images"]


def test_last_checkpoint_is_the_last_epoch_even_between_validations(tmp_path):
    # validation (and the best-PSNR checkpoint) every 2 epochs, 3 epochs of 2 steps: last.ckpt must hold step 6
    main(_quick(tmp_path / "a", 3, ["--trainer.check_val_every_n_epoch", "2"]))
    last = torch.load(tmp_path / "a" / "version_0" / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 6  # the weights after the final step (epoch 3 of 3 completed)


def test_predict_writes_dng_files_a_raw_reader_opens(tmp_path):
    import rawpy

    from rawaug.io.dng import write_dng

    noisy = tmp_path / "noisy"
    noisy.mkdir()
    mosaic = np.random.default_rng(0).integers(600, 900, (48, 64)).astype(np.uint16)
    write_dng(noisy / "shot.dng", mosaic, cfa="GRBG", black_level=600, white_level=4095, iso=3200, exposure_s=0.01)
    args = ["predict", "--config", str(REPO / "configs" / "quickstart.yaml"), *_small(tmp_path),
            "--data.init_args.predict=rawaug.train.NoisyFolder", f"--data.init_args.predict.root={noisy}",
            "--data.init_args.predict.ratio=10", "--trainer.callbacks+=rawaug.train.DenoisedWriter",
            f"--trainer.callbacks.output_dir={tmp_path / 'out'}", "--trainer.callbacks.format=both"]
    main(args)
    packed = np.load(tmp_path / "out" / "shot.npy")
    with rawpy.imread(str(tmp_path / "out" / "shot.dng")) as raw:
        assert raw.raw_image.shape == (48, 64)
        assert [int(v) for v in raw.black_level_per_channel] == [600] * 4 and raw.white_level == 4095
        assert "".join(chr(raw.color_desc[c]) for c in raw.raw_pattern.ravel()) == "GRBG"
        from rawaug.bayer import pack

        codes = pack(raw.raw_image.astype(np.float64), "GRBG")
    # the DNG holds the .npy output in raw codes, rounded
    assert np.abs(codes - (packed * (4095 - 600) + 600)).max() <= 0.5 + 1e-3
