"""Train, validate, test and run the raw denoiser from a YAML config.

    python lightning_app/fit.py fit --config configs/quickstart.yaml
    python lightning_app/fit.py test --config configs/sid_GsPsRU.yaml --ckpt_path last.ckpt
"""
import logging
import warnings

from lightning.pytorch.cli import LightningCLI

# Notices of a normal run that ask nothing of a user, silenced here in the app (not in the library):
# Lightning 2.6's advertisement for its cloud logger, printed on every fit, and torch's deprecation
# of LeafSpec, which lightning 2.6.6's own pytree code still uses.
warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated", category=FutureWarning)


class _NoAdvertisement(logging.Filter):
    def filter(self, record):
        return not str(record.msg).startswith("\N{ELECTRIC LIGHT BULB} Tip:")


for _name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero"):
    logging.getLogger(_name).addFilter(_NoAdvertisement())

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
