"""Train, validate, test and run the raw denoiser from a YAML config.

    python lightning_app/fit.py fit --config configs/quickstart.yaml
    python lightning_app/fit.py test --config configs/sid_GsPsRU.yaml --ckpt_path last.ckpt
"""
from lightning.pytorch.cli import LightningCLI

from rawaug.train import DenoiseModule, RawDenoiseData


def main(args=None):
    """Build the Lightning CLI (``args``: a list of CLI arguments, default ``sys.argv``)."""
    return LightningCLI(DenoiseModule, datamodule_class=RawDenoiseData, subclass_mode_data=True, args=args,
                        save_config_kwargs={"overwrite": True})


if __name__ == "__main__":
    import sys

    try:
        main()
    except (FileNotFoundError, NotADirectoryError) as exc:  # data not where the config says: one line
        print(f"fit.py: error: {exc}", file=sys.stderr)
        sys.exit(2)
